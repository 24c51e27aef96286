"""The exact model's thresholds switched off: its time and outcome, on held-out seeds.

    python benchmarks/exact_model_thresholds.py                  # seeds 301-306
    python benchmarks/exact_model_thresholds.py --seeds 301 302

:func:`moju_core.completion.exact_model.exact_model` is run on each case under the closing
occlusion (a band over 20 % of the width, 10 % of the tracks lost, 2 % dropout) once with the
code as it is and once per threshold at its neutral setting (the settings of
``benchmarks/rule_ablation.py``). Recorded: the time, whether a model came back and whether it
is exact. The full solves are in ``rule_ablation.py``; this measures what those do not show, the
cost of the candidates that the held-out test then refuses.

Writes ``exact_model_thresholds.json`` and ``.md`` into ``--output-dir`` (default
``benchmarks/results/rules/thresholds-followup``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from harness import RESULTS, provenance, table, write_json, write_markdown
from rule_ablation import HELD_OUT_SEEDS, patched

from moju_core.completion import exact_model, window_subspace
from moju_core.datasets import make_sequence, occlusion_mask

#: (name, neutral setting): the thresholds of the exact model's candidates.
SETTINGS: tuple[tuple[str, tuple[tuple[Any, str, Any], ...]], ...] = (
    ("as is", ()),
    ("LOW_RANK_FRACTION = 1", ((window_subspace, "LOW_RANK_FRACTION", 1.0),)),
    ("SPARE_GAP = 0", ((exact_model, "SPARE_GAP", 0.0),)),
    ("WINDOW_LENGTHS = (12,)", ((window_subspace, "WINDOW_LENGTHS", (12,)),)),
)
#: (sequence, frames, points, noise): exactly low-rank tracks and noisy ones.
CASES = (
    ("face3", 99, 2000, 0.0),
    ("cloth", 60, 2000, 0.0),
    ("bumps-osc", 60, 2000, 0.0),
    ("face3", 99, 2000, 0.01),
    ("cloth", 60, 2000, 0.01),
)


def run(case: tuple[str, int, int, float], seed: int) -> list[dict[str, Any]]:
    """Every setting on one case and seed."""
    name, frames, points, noise = case
    data = make_sequence(name, n_frames=frames, n_points=points, seed=seed, noise=noise)
    visibility = occlusion_mask(data, seed=seed, band=0.2, lost=0.1, dropout=0.02)
    rows = []
    for setting, patches in SETTINGS:
        with patched(patches):
            start = time.perf_counter()
            model = exact_model.exact_model(data.W, visibility)
            seconds = time.perf_counter() - start
        rows.append(
            {
                "case": f"{name} {frames}x{points}" + (f", noise {noise:g}" if noise else ""),
                "seed": seed,
                "setting": setting,
                "seconds": seconds,
                "model": model is not None,
                "exact": bool(model is not None and model.exact),
            }
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=list(HELD_OUT_SEEDS))
    parser.add_argument(
        "--output-dir", type=Path, default=RESULTS / "rules" / "thresholds-followup"
    )
    args = parser.parse_args(argv)
    meta = provenance(sys.argv if argv is None else ["exact_model_thresholds.py", *argv])
    rows = []
    for case in CASES:
        for seed in args.seeds:
            for row in run(case, seed):
                rows.append(row)
                print(
                    f"{row['case']:26s} seed {seed:3d} {row['setting']:24s} "
                    f"{row['seconds']:7.3f} s  model {row['model']!s:5s} exact {row['exact']!s}",
                    flush=True,
                )
    summary = []
    for case in dict.fromkeys(r["case"] for r in rows):
        for setting, _ in SETTINGS:
            chosen = [r for r in rows if r["case"] == case and r["setting"] == setting]
            summary.append(
                (
                    case,
                    setting,
                    f"{statistics.fmean(r['seconds'] for r in chosen):.3f}",
                    f"{sum(r['exact'] for r in chosen)} of {len(chosen)}",
                )
            )
    args.output_dir.mkdir(parents=True, exist_ok=True)
    write_json(args.output_dir / "exact_model_thresholds.json", meta, rows=rows)
    write_markdown(
        args.output_dir / "exact_model_thresholds.md",
        "The exact model's thresholds switched off",
        meta,
        table(("case", "setting", "mean seconds", "exact model"), summary),
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
