"""How far moju can go on the hard sequences when everything but the shapes is given: the true
cameras, and the smoothness weight and number of unshrunk values chosen with hindsight.

    python benchmarks/ceiling.py --seeds 28 29 30 31 --points 1000 --jobs 2

For every sequence and seed, moju runs with the true rotations once with its own rules and
once per (``smoothness``, ``unshrunk_values``) of the grid; the row keeps the best e3D of the
grid and where it was reached, PTA with the true rotations, and the best rigid e3D (one shape
fitted to the truth). The hard-sequence target for estimated cameras is half the best rigid
e3D: where even the best of the grid with the true cameras stays above it, no camera
estimator can reach it with this model. Writes ``ceiling.json`` and ``ceiling.md`` into
``--output-dir``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

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

from moju_core.datasets import HARD_SEQUENCE_NAMES, make_sequence
from moju_core.metrics import e3d, rigid_approximation

WEIGHTS = (0.0, 10.0, 100.0, 1_000.0, 100_000.0)
UNSHRUNK = (1, 4, 8)


def run_unit(
    name: str, seed: int, n_points: int, weights: tuple[float, ...], unshrunk: tuple[int, ...]
) -> dict[str, Any]:
    """The default solve, PTA and every grid point of one sequence and seed, true cameras."""
    data = make_sequence(name, n_points=n_points, seed=seed)
    rigid = e3d(rigid_approximation(data.shapes), data.shapes)
    default = solve(data, "moju", seed=seed)
    grid = {
        (w, u): solve(data, "moju", seed=seed, smoothness=w, unshrunk_values=u)["e3d"]
        for w in weights
        for u in unshrunk
    }
    best = min(grid, key=grid.get)
    row = {
        "sequence": name,
        "seed": seed,
        "n_points": data.n_points,
        "best_rigid": rigid,
        "target": rigid / 2,
        "default": default["e3d"],
        "default_smoothness": default["smoothness"],
        "pta": solve(data, "pta", seed=seed)["e3d"],
        "best": grid[best],
        "best_smoothness": best[0],
        "best_unshrunk": best[1],
        "grid": [[w, u, e] for (w, u), e in grid.items()],
    }
    print(
        f"{name} s{seed}: half best rigid {rigid / 2:.4f}, default {row['default']:.4f}, "
        f"best {row['best']:.4f} (w={best[0]:g}, u={best[1]}), pta {row['pta']:.4f}",
        flush=True,
    )
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequences", nargs="+", default=list(HARD_SEQUENCE_NAMES))
    parser.add_argument("--seeds", nargs="+", type=int, default=[28, 29, 30, 31])
    parser.add_argument("--points", type=int, default=1_000)
    parser.add_argument("--weights", nargs="+", type=float, default=list(WEIGHTS))
    parser.add_argument("--unshrunk", nargs="+", type=int, default=list(UNSHRUNK))
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--output-dir", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    meta = provenance(sys.argv if argv is None else ["ceiling.py", *argv])
    units = [
        (name, seed, args.points, tuple(args.weights), tuple(args.unshrunk))
        for name in args.sequences
        for seed in args.seeds
    ]
    rows = parallel_map(run_unit, units, args.jobs)
    args.output_dir.mkdir(parents=True, exist_ok=True)
    write_json(args.output_dir / "ceiling.json", meta, rows=rows)
    header = ["sequence", "seeds", "half best rigid", "moju (default)", "best of grid", "pta"]
    header += ["grid best below half best rigid"]
    body = []
    for name in args.sequences:
        sub = [r for r in rows if r["sequence"] == name]
        below = sum(r["best"] <= r["target"] for r in sub)
        body.append(
            [name, " ".join(str(r["seed"]) for r in sub)]
            + [f"{mean(r[k] for r in sub):.4f}" for k in ("target", "default", "best", "pta")]
            + [f"{below} of {len(sub)}"]
        )
    detail = [
        [r["sequence"], r["seed"], f"{r['target']:.4f}", f"{r['default']:.4f}"]
        + [f"{r['default_smoothness']:g}", f"{r['best']:.4f}"]
        + [f"{r['best_smoothness']:g}", r["best_unshrunk"], f"{r['pta']:.4f}"]
        for r in rows
    ]
    write_markdown(
        args.output_dir / "ceiling.md",
        "Hard sequences with the true cameras and hindsight parameters",
        meta,
        [
            f"e3D (per-frame Procrustes), true rotations, {args.points:,} points. 'best of "
            f"grid': the lowest e3D over smoothness {', '.join(f'{w:g}' for w in args.weights)}"
            f" x unshrunk values {', '.join(map(str, args.unshrunk))}, chosen with hindsight. "
            "The target for estimated cameras is half the best rigid e3D.",
            "",
            *table(header, body),
            "",
            "## Per seed",
            "",
            *table(
                ["sequence", "seed", "half best rigid", "moju", "weight", "best of grid"]
                + ["best weight", "best unshrunk", "pta"],
                detail,
            ),
        ],
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
