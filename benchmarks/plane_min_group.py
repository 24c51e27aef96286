"""The plane estimator's MIN_GROUP_SIZE at 8 (the code) and at 3 (a plane's minimum).

    python benchmarks/plane_min_group.py                        # held-out seeds 301-306
    python benchmarks/plane_min_group.py --noise 0.01 --seeds 301 302

:data:`moju_core.cameras.plane.MIN_GROUP_SIZE` acts only where the tracks are too few for the
requested groups (below 32 tracks for the default 4 groups), so the cases are a few tracks of
the sheet sequences. For each case and seed, the mean rotation error (degrees) of
:func:`moju_core.cameras.plane.plane_rotations` with the default groups, the group sizes, and
the ratio of the largest IRLS weight to the next (a ratio near 1e6 or more: the fit has
collapsed onto one group).

Writes ``plane_min_group_<noise>.json`` and ``.md`` into ``--output-dir`` (default
``benchmarks/results/rules/min_group_size``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path
from typing import Any

import numpy as np
from harness import RESULTS, provenance, table, write_json, write_markdown
from rule_ablation import HELD_OUT_SEEDS

from moju_core.cameras import plane
from moju_core.datasets import make_sequence
from moju_core.metrics import rotation_errors_deg
from moju_core.spectrum import noise_variance

SEQUENCES = ("flag-osc", "flag-turn", "bumps-osc", "cloth")
POINTS = (12, 16, 24)
VALUES = (8, 3)


def run(W: np.ndarray, truth: np.ndarray, value: int, variance: float) -> dict[str, Any]:
    """The plane rotations with MIN_GROUP_SIZE = value."""
    saved = plane.MIN_GROUP_SIZE
    plane.MIN_GROUP_SIZE = value
    try:
        labels = plane.group_labels(W, plane.DEFAULT_GROUPS)
        weights, _, _ = plane.group_weights(W, labels, variance)
        rotations = plane.plane_rotations(W, noise_variance=variance)
    finally:
        plane.MIN_GROUP_SIZE = saved
    ordered = np.sort(weights)[::-1]
    return {
        "error_deg": float(rotation_errors_deg(rotations, truth).mean()),
        "sizes": np.bincount(labels).tolist(),
        "weight_ratio": float(ordered[0] / max(ordered[1], 1e-300)) if ordered.size > 1 else 1.0,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=list(HELD_OUT_SEEDS))
    parser.add_argument("--noise", type=float, default=0.0)
    parser.add_argument("--output-dir", type=Path, default=RESULTS / "rules" / "min_group_size")
    args = parser.parse_args(argv)
    meta = provenance(sys.argv if argv is None else ["plane_min_group.py", *argv])
    rows = []
    for name in SEQUENCES:
        for points in POINTS:
            for seed in args.seeds:
                data = make_sequence(name, n_points=points, seed=seed, noise=args.noise)
                W = data.W - data.W.mean(axis=1, keepdims=True)
                variance = 0.0
                if args.noise:
                    variance = noise_variance(np.linalg.svd(W, compute_uv=False), W.shape)
                row: dict[str, Any] = {"sequence": name, "points": points, "seed": seed}
                for value in VALUES:
                    row[str(value)] = run(W, data.rotations, value, variance)
                rows.append(row)
                print(
                    f"{name:10s} {points:3d} tracks seed {seed:3d}  "
                    + "  ".join(
                        f"{v}: {row[str(v)]['error_deg']:6.2f} deg {row[str(v)]['sizes']} "
                        f"ratio {row[str(v)]['weight_ratio']:.1e}"
                        for v in VALUES
                    ),
                    flush=True,
                )
    summary = []
    for name in SEQUENCES:
        for points in POINTS:
            chosen = [r for r in rows if r["sequence"] == name and r["points"] == points]
            means = [statistics.fmean(r[str(v)]["error_deg"] for r in chosen) for v in VALUES]
            lower = sum(r["8"]["error_deg"] < r["3"]["error_deg"] - 0.1 for r in chosen)
            higher = sum(r["8"]["error_deg"] > r["3"]["error_deg"] + 0.1 for r in chosen)
            summary.append(
                (name, points, *(f"{m:.2f}" for m in means), f"{lower} / {higher} of {len(chosen)}")
            )
    stem = f"plane_min_group_{args.noise:g}"
    args.output_dir.mkdir(parents=True, exist_ok=True)
    write_json(args.output_dir / f"{stem}.json", meta, rows=rows)
    write_markdown(
        args.output_dir / f"{stem}.md",
        f"Plane estimator, MIN_GROUP_SIZE 8 against 3 (noise {args.noise:g})",
        meta,
        table(
            (
                "sequence",
                "tracks",
                "mean error at 8 (deg)",
                "at 3",
                "8 lower / higher by > 0.1 deg",
            ),
            summary,
        ),
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
