"""What each part of the noisy missing-data path does: e3D with both parts, without the
trust-by-precision rule (:func:`moju_core.completion.missing.trusted_entries` with ``noisy``
ignored),
and without the signal fit on the completed tracks (``solve_plan.tries_signal_fit`` false).

    python benchmarks/noisy_missing_ablation.py --seeds 6 8 --noise 0.02

Known rotations, the missing-data closing occlusion (band, lost tracks and dropout), 1,000
points. Writes ``noisy_missing_ablation.{json,md}`` into ``--output-dir``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from harness import RESULTS, provenance, solve, table, write_json, write_markdown

from moju_core import solve_plan
from moju_core.completion import missing
from moju_core.datasets import make_sequence, occlusion_mask

CLOSING = {"band": 0.2, "lost": 0.1, "dropout": 0.02}
VARIANTS = ("both", "no trust rule", "no signal fit")


def run_variant(data: Any, seed: int, variant: str) -> float:
    """e3D of one solve with the named part switched off (restored afterwards)."""
    trusted, tries = missing.trusted_entries, solve_plan.tries_signal_fit
    if variant == "no trust rule":
        missing.trusted_entries = lambda model, seen, noisy=False: trusted(model, seen)
    if variant == "no signal fit":
        solve_plan.tries_signal_fit = lambda *args: False
    try:
        visibility = occlusion_mask(data, **CLOSING, seed=seed)
        return solve(data, "moju", seed=seed, visibility=visibility)["e3d"]
    finally:
        missing.trusted_entries, solve_plan.tries_signal_fit = trusted, tries


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--sequences",
        nargs="+",
        default=["bumps-osc", "flag-osc", "cloth", "paper", "face3", "face2"],
    )
    parser.add_argument("--seeds", nargs="+", type=int, default=[6, 8])
    parser.add_argument("--noise", type=float, default=0.02)
    parser.add_argument("--points", type=int, default=1_000)
    parser.add_argument("--output-dir", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    meta = provenance(sys.argv if argv is None else ["noisy_missing_ablation.py", *argv])
    rows = []
    for name in args.sequences:
        for seed in args.seeds:
            data = make_sequence(name, n_points=args.points, noise=args.noise, seed=seed)
            row = {"sequence": name, "seed": seed, "noise": args.noise}
            row.update({v: run_variant(data, seed, v) for v in VARIANTS})
            print(row, flush=True)
            rows.append(row)
    write_json(args.output_dir / "noisy_missing_ablation.json", meta, rows=rows)
    body = [[r["sequence"], r["seed"], *(f"{r[v]:.4f}" for v in VARIANTS)] for r in rows]
    write_markdown(
        args.output_dir / "noisy_missing_ablation.md",
        f"Noisy tracks with missing entries: each part switched off (lambda_g {args.noise:g})",
        meta,
        table(["sequence", "seed", *VARIANTS], body),
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
