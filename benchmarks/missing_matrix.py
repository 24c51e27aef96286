"""Missing data beyond the closing cases: complete against missing tracks on every kind of
sequence, noise level and camera source.

    python benchmarks/missing_matrix.py --seeds 38 39 --jobs 2
    python benchmarks/missing_matrix.py --seeds 40 --noise 0 --sequences face4-41 body-osc-41

Each cell solves one sequence twice with moju, once complete and once under the missing-data
closing configuration (:data:`CLOSING`: an occluder band over 20 % of the width, 10 % of the
tracks lost from a random frame on, 2 % random entries), and scores both against the same
ground truth (per-frame Procrustes e3D over all points). The target is the missing-data
issue's, e3D <= 1.25 x complete + 0.005. The time ratio comes from one run of each on a
shared machine and is indicative only (``benchmarks/missing.py`` times the closing cases by
medians of interleaved runs). Writes ``missing_matrix.{json,md}`` into ``--output-dir``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from harness import RESULTS, parallel_map, provenance, solve, table, write_json, write_markdown

from moju_core.datasets import make_sequence, occlusion_mask

CLOSING = {"band": 0.2, "lost": 0.1, "dropout": 0.02}
E3D_FACTOR, E3D_SLACK = 1.25, 0.005
#: Name -> (sequence, points, frames or None for the sequence's own): dense faces and sheets
#: at 1,000 points, and 41 markers of a face and of an articulated body over 350 frames.
CASES: dict[str, tuple[str, int, int | None]] = {
    "face1": ("face1", 1_000, None),
    "face2": ("face2", 1_000, None),
    "face3": ("face3", 1_000, None),
    "face4": ("face4", 1_000, None),
    "paper": ("paper", 1_000, None),
    "cloth": ("cloth", 1_000, None),
    "bumps-osc": ("bumps-osc", 1_000, None),
    "flag-osc": ("flag-osc", 1_000, None),
    "face4-41": ("face4", 41, 350),
    "body-osc-41": ("body-osc", 41, 350),
}


def cell(case: str, noise: float, seed: int, source: str) -> dict[str, Any]:
    """Complete and missing solves of one case; the row of the table."""
    name, n_points, n_frames = CASES[case]
    data = make_sequence(name, n_points=n_points, n_frames=n_frames, noise=noise, seed=seed)
    visibility = occlusion_mask(data, **CLOSING, seed=seed)
    complete = solve(data, "moju", rotation_source=source, seed=seed)
    missing = solve(data, "moju", rotation_source=source, seed=seed, visibility=visibility)
    target = E3D_FACTOR * complete["e3d"] + E3D_SLACK
    row = {
        "case": case,
        "noise": noise,
        "seed": seed,
        "rotations": source,
        "missing": 1.0 - missing["observed_fraction"],
        "e3d_complete": complete["e3d"],
        "e3d_missing": missing["e3d"],
        "e3d_target": target,
        "e3d_met": missing["e3d"] <= target,
        "rotation_error_complete_deg": complete["rotation_error_deg"],
        "rotation_error_missing_deg": missing["rotation_error_deg"],
        "time_ratio": missing["seconds"] / complete["seconds"],
    }
    print(
        f"{case} noise {noise:g} seed {seed} {source}: e3D {complete['e3d']:.4f} -> "
        f"{missing['e3d']:.4f} ({'met' if row['e3d_met'] else 'missed'})",
        flush=True,
    )
    return row


def summary(rows: list[dict[str, Any]]) -> list[str]:
    """Targets met per case and camera source, over the noise levels and seeds."""
    body = []
    for case in dict.fromkeys(r["case"] for r in rows):
        for source in ("known", "estimated"):
            cells = [r for r in rows if r["case"] == case and r["rotations"] == source]
            if cells:
                met = sum(r["e3d_met"] for r in cells)
                ratios = sorted(r["e3d_missing"] / r["e3d_complete"] for r in cells)
                body.append([case, source, f"{met} of {len(cells)}",
                             f"{ratios[0]:.2f}-{ratios[-1]:.2f}"])  # fmt: skip
    header = ["case", "rotations", "target met", "e3D missing / complete"]
    return table(header, body)


def details(rows: list[dict[str, Any]]) -> list[str]:
    body = [
        [
            r["case"],
            f"{r['noise']:g}",
            r["seed"],
            r["rotations"],
            f"{100 * r['missing']:.1f}",
            f"{r['e3d_complete']:.4f}",
            f"{r['e3d_missing']:.4f}",
            f"{r['e3d_target']:.4f}",
            "met" if r["e3d_met"] else "**missed**",
            f"{r['rotation_error_complete_deg']:.1f} / {r['rotation_error_missing_deg']:.1f}",
            f"{r['time_ratio']:.2f}",
        ]
        for r in rows
    ]
    header = ["case", "lambda_g", "seed", "rotations", "missing %", "e3D complete"]
    header += ["e3D missing", "target", "e3D", "rotation error (deg)", "time ratio (1 run)"]
    return table(header, body)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequences", nargs="+", choices=sorted(CASES), default=list(CASES))
    parser.add_argument("--seeds", nargs="+", type=int, default=[38, 39])
    parser.add_argument("--noise", nargs="+", type=float, default=[0.0, 0.0005, 0.01])
    parser.add_argument("--rotations", nargs="+", default=["known", "estimated"])
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--output-dir", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    meta = provenance(sys.argv if argv is None else ["missing_matrix.py", *argv])
    units = [
        (case, noise, seed, source)
        for case in args.sequences
        for noise in args.noise
        for seed in args.seeds
        for source in args.rotations
    ]
    rows = parallel_map(cell, units, args.jobs)
    write_json(args.output_dir / "missing_matrix.json", meta, rows=rows)
    intro = [
        f"moju, complete tracks against the closing occlusion ({CLOSING}); target e3D <= "
        f"{E3D_FACTOR} x complete + {E3D_SLACK}. Dense cases at 1,000 points, '-41' cases "
        "41 markers over 350 frames. Estimated rotations are the solver's own camera step.",
        "",
    ]
    write_markdown(
        args.output_dir / "missing_matrix.md",
        "Missing data on every kind of sequence",
        meta,
        [*intro, *summary(rows), "", *details(rows)],
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
