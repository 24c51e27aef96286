"""The smoothness rule against the best fixed weight: e3D of the full solve for every weight of
``moju_core.priors.smoothness.SMOOTHNESS_GRID`` next to the weight the rule chose.

    python benchmarks/smoothness_oracle.py                                   # hard + faces
    python benchmarks/smoothness_oracle.py --sequences face3 bumps-osc --seeds 2 3 --jobs 2

For every sequence, seed and rotation source the default solve runs once (``smoothness``
derived from the data; the row records the chosen weight and the rule's trial misfits) and once
per fixed weight, with every other default left to its rule (``unshrunk_values`` follows the
weight as it does after the rule). ``regret`` is the e3D of the chosen weight over the best of
the grid. Writes ``smoothness_oracle.json`` and ``smoothness_oracle.md`` into ``--output-dir``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from hard import FACE_NAMES as FACES
from harness import (
    RESULTS,
    mean,
    parallel_map,
    provenance,
    solve,
    table,
    write_json,
    write_markdown,
)
from threadpoolctl import threadpool_limits

from moju_core.datasets import HARD_SEQUENCE_NAMES, make_sequence
from moju_core.priors.smoothness import SMOOTHNESS_GRID

WEIGHTS = SMOOTHNESS_GRID


def run_unit(
    name: str, seed: int, n_points: int, source: str, weights: tuple[float, ...]
) -> dict[str, Any]:
    """The auto solve and one solve per fixed weight of one sequence, seed and camera source."""
    data = make_sequence(name, n_points=n_points, seed=seed)
    row: dict[str, Any] = {"sequence": name, "seed": seed, "rotations": source}
    row["n_points"] = data.n_points
    for weight in (None, *weights):
        with threadpool_limits(limits=1):
            solved = solve(data, "moju", rotation_source=source, seed=seed, smoothness=weight)
        if weight is None:
            row["chosen"] = solved["smoothness"]
            row["auto"] = solved["e3d"]
            row["trials"] = solved["smoothness_trials"]
        else:
            row[f"w{weight:g}"] = solved["e3d"]
    grid = {w: row[f"w{w:g}"] for w in weights}
    row["best_weight"] = min(grid, key=grid.get) if grid else None
    row["regret"] = row["auto"] / grid[row["best_weight"]] if grid else None
    print(describe(row), flush=True)
    return row


def describe(row: dict[str, Any]) -> str:
    grid = " ".join(f"{k}={v:.4f}" for k, v in row.items() if k.startswith("w"))
    best = (
        ""
        if row["regret"] is None
        else (f", best {row['best_weight']:g}, regret {row['regret']:.2f}")
    )
    return (
        f"{row['sequence']} s{row['seed']} {row['rotations']}: auto {row['auto']:.4f} "
        f"(chose {row['chosen']:g}{best}) {grid}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequences", nargs="+", default=[*HARD_SEQUENCE_NAMES, *FACES])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3])
    parser.add_argument("--rotations", nargs="+", default=["known"])
    parser.add_argument("--hard-points", type=int, default=10_000)
    parser.add_argument("--face-points", type=int, default=2_000)
    parser.add_argument(
        "--weights", nargs="*", type=float, default=list(WEIGHTS), help="fixed weights to run"
    )
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--output-dir", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    weights = tuple(args.weights)
    meta = provenance(sys.argv if argv is None else ["smoothness_oracle.py", *argv])
    units = [
        (name, seed, args.face_points if name in FACES else args.hard_points, source, weights)
        for name in args.sequences
        for seed in args.seeds
        for source in args.rotations
    ]
    rows = parallel_map(run_unit, units, args.jobs)
    args.output_dir.mkdir(parents=True, exist_ok=True)
    write_json(args.output_dir / "smoothness_oracle.json", meta, rows=rows)
    header = ["sequence", "seed", "rotations", "chosen", "auto"]
    header += [*(f"w={w:g}" for w in weights), "regret"]
    body = [
        [r["sequence"], r["seed"], r["rotations"], f"{r['chosen']:g}", f"{r['auto']:.4f}"]
        + [f"{r[f'w{w:g}']:.4f}" for w in weights]
        + ["-" if r["regret"] is None else f"{r['regret']:.2f}"]
        for r in rows
    ]
    regrets = [r["regret"] for r in rows if r["regret"] is not None]
    summary = (
        [f"Mean regret (auto e3D over the best weight's): {mean(regrets):.3f}"] if regrets else []
    )
    write_markdown(
        args.output_dir / "smoothness_oracle.md",
        "The smoothness rule against the best fixed weight",
        meta,
        [*summary, "", *table(header, body)],
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
