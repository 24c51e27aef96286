"""The camera table: rotation error of every estimator, and e3D with known and estimated rotations.

    python benchmarks/cameras.py rotations --seeds 0 1 2 10 11 12 13 --jobs 2
    python benchmarks/cameras.py e3d --sequences flag-osc bumps-osc --seeds 0 1 2 10 11 12 13

``rotations``: every estimator alone (no solve) on the stress set (sheets under oscillating
cameras and slow turntables, the waving cloth, the markers on an articulated body, a face) at
the given noise levels: the mean rotation error after one global alignment
(:func:`moju_core.metrics.rotation_errors_deg`), and the frame-to-frame error, the angle of
``A_{f+1} A_f^T (B_{f+1} B_f^T)^T`` for the estimated (A) and aligned true (B) rotations,
median and maximum over the sequence. ``plane G1`` is :func:`moju_core.cameras.plane.
plane_rotations` with one group (the ablation), ``plane G<n>`` with n groups.

``e3d``: ``moju_core.reconstruct`` with the true rotations, with ``rotations="auto"`` (which
refines windowed rotations in the loop), and with the plane rotations passed as
``rotations="known"`` (not refined: the plane estimator is not wired into ``"auto"``).

Seeds 0-2 were used to design the estimator; 10-13 are held out. Writes
``cameras_rotations.{json,md}`` / ``cameras_e3d.{json,md}`` into ``--output-dir``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from harness import RESULTS, parallel_map, provenance, table, write_json, write_markdown
from threadpoolctl import threadpool_limits

from moju_core import SolverParams, reconstruct
from moju_core.cameras import estimate_cameras
from moju_core.cameras.plane import plane_rotations
from moju_core.cameras.refinement import project_to_stiefel
from moju_core.datasets import make_sequence
from moju_core.metrics import evaluate, rotation_errors_deg
from moju_core.preprocessing import normalise
from moju_core.spectrum import noise_variance, spectrum

OUTPUT = RESULTS / "cameras"
SEQUENCES = (
    "flag-osc", "flag-turn", "bumps-osc", "roll-osc", "cloth", "body-osc", "body-turn", "face3",
)  # fmt: skip
DESIGN_SEEDS = (0, 1, 2)
NOISES = (0.0, 0.01, 0.03, 0.055)
ESTIMATORS = ("rigid", "windowed", "intersection", "auto", "plane G1", "plane G4", "plane G10")


def load(name: str, seed: int, noise: float, n_points: int):
    """A stress sequence; the body has its 41 markers whatever ``n_points`` says."""
    points = 41 if name.startswith("body") else n_points
    return make_sequence(name, n_points=points, noise=noise, seed=seed)


def _complete(rows: np.ndarray) -> np.ndarray:
    rows = project_to_stiefel(rows)
    return np.concatenate([rows, np.cross(rows[:, 0], rows[:, 1])[:, None]], axis=1)


def frame_to_frame_deg(R_est: np.ndarray, R_true: np.ndarray) -> np.ndarray:
    """Error of the relative rotations ``R_{f+1} R_f^T`` (degrees, (F - 1,)), after the global
    alignment of :func:`moju_core.metrics.rotation_errors_deg`."""
    Q = project_to_stiefel(R_true.reshape(-1, 3).T @ R_est.reshape(-1, 3))
    A, B = _complete(R_est), _complete(R_true @ Q)
    rel_a = A[1:] @ np.swapaxes(A[:-1], 1, 2)
    rel_b = B[1:] @ np.swapaxes(B[:-1], 1, 2)
    cosine = (np.einsum("fij,fij->f", rel_a, rel_b) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def estimate(W: np.ndarray, name: str, seed: int) -> np.ndarray:
    """Rotations of centred tracks by one of :data:`ESTIMATORS`."""
    if name.startswith("plane"):
        variance = noise_variance(spectrum(W).singular, W.shape)
        groups = int(name.split("G")[1])
        return plane_rotations(W, n_groups=groups, noise_variance=variance, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return estimate_cameras(W, name, seed=seed).rotations


def rotation_unit(
    name: str, seed: int, noise: float, n_points: int, estimators: tuple[str, ...] = ESTIMATORS
) -> list[dict[str, Any]]:
    data = load(name, seed, noise, n_points)
    W, _ = normalise(data.W)
    rows = []
    with threadpool_limits(limits=1):
        for estimator in estimators:
            start = time.perf_counter()
            R = estimate(W, estimator, seed)
            seconds = time.perf_counter() - start
            step = frame_to_frame_deg(R, data.rotations)
            rows.append(
                {
                    "sequence": name, "seed": seed, "noise": noise, "estimator": estimator,
                    "held_out": seed not in DESIGN_SEEDS,
                    "n_frames": data.n_frames, "n_points": data.n_points,
                    "rotation_error_deg": float(rotation_errors_deg(R, data.rotations).mean()),
                    "f2f_median_deg": float(np.median(step)), "f2f_max_deg": float(step.max()),
                    "seconds": seconds,
                }
            )  # fmt: skip
    print(
        f"{name} s{seed} n{noise}: "
        + " ".join(f"{r['estimator']}={r['rotation_error_deg']:.1f}" for r in rows),
        flush=True,
    )
    return rows


def _solve(data, rotations: np.ndarray | None, seed: int) -> dict[str, Any]:
    params = SolverParams(
        method="moju", seed=seed, rotations="known" if rotations is not None else "auto"
    )
    with warnings.catch_warnings(), threadpool_limits(limits=1):
        warnings.simplefilter("ignore")
        start = time.perf_counter()
        result = reconstruct(data.W, params, rotations=rotations)
        seconds = time.perf_counter() - start
    scores = evaluate(result.shapes, data.shapes, result.rotations, data.rotations)
    return {
        "e3d": scores["e3d_procrustes"],
        "rotation_error_deg": scores["rotation_error_deg"],
        "seconds": seconds,
        "source": result.diagnostics.rotation_source,
    }


def e3d_unit(name: str, seed: int, noise: float, n_points: int) -> dict[str, Any]:
    data = load(name, seed, noise, n_points)
    W, _ = normalise(data.W)
    variance = noise_variance(spectrum(W).singular, W.shape)
    row: dict[str, Any] = {
        "sequence": name, "seed": seed, "noise": noise, "held_out": seed not in DESIGN_SEEDS,
        "n_points": data.n_points, "n_frames": data.n_frames,
    }  # fmt: skip
    row["known"] = _solve(data, data.rotations, seed)
    row["auto"] = _solve(data, None, seed)
    for groups in (1, 4):
        start = time.perf_counter()
        R = plane_rotations(W, n_groups=groups, noise_variance=variance, seed=seed)
        seconds = time.perf_counter() - start
        solved = _solve(data, R, seed)
        solved["seconds"] += seconds
        solved["rotation_error_deg"] = float(rotation_errors_deg(R, data.rotations).mean())
        row[f"plane G{groups}"] = solved
    print(
        f"{name} s{seed} n{noise}: known {row['known']['e3d']:.4f} auto {row['auto']['e3d']:.4f} "
        f"plane G1 {row['plane G1']['e3d']:.4f} G4 {row['plane G4']['e3d']:.4f}",
        flush=True,
    )
    return row


def _mean(values: list[float]) -> str:
    return f"{float(np.mean(values)):.2f}" if values else "-"


def rotation_tables(
    rows: list[dict[str, Any]], sequences: list[str], noises: list[float]
) -> list[str]:
    lines: list[str] = []
    for held_out in (False, True):
        lines += ["", f"## {'Held-out' if held_out else 'Design'} seeds", ""]
        header = ["sequence", "noise"] + list(ESTIMATORS)
        body = []
        for name in sequences:
            for noise in noises:
                cells = []
                for estimator in ESTIMATORS:
                    sub = [
                        r for r in rows
                        if r["sequence"] == name and r["noise"] == noise
                        and r["estimator"] == estimator and r["held_out"] == held_out
                    ]  # fmt: skip
                    if not sub:
                        cells.append("-")
                        continue
                    cells.append(
                        f"{_mean([r['rotation_error_deg'] for r in sub])} / "
                        f"{_mean([r['f2f_median_deg'] for r in sub])} / "
                        f"{max(r['f2f_max_deg'] for r in sub):.1f}"
                    )
                body.append([name, f"{noise:g}", *cells])
        lines += table(header, body)
    seconds = [
        [estimator, _mean([r["seconds"] for r in rows if r["estimator"] == estimator])]
        for estimator in ESTIMATORS
    ]
    lines += ["", "Mean seconds per estimate (one BLAS thread):", "", *table(["", "s"], seconds)]
    return lines


def e3d_tables(rows: list[dict[str, Any]]) -> list[str]:
    keys = ("known", "auto", "plane G1", "plane G4")
    header = ["sequence", "seed", "noise"] + [f"{k} e3D (rot deg)" for k in keys]
    header += ["plane G1 / known"]
    body = [
        [r["sequence"], f"{r['seed']}{'*' if r['held_out'] else ''}", f"{r['noise']:g}"]
        + [f"{r[k]['e3d']:.4f} ({r[k]['rotation_error_deg']:.1f})" for k in keys]
        + [f"{r['plane G1']['e3d'] / r['known']['e3d']:.2f}"]
        for r in rows
    ]
    summary = []
    for name in sorted({r["sequence"] for r in rows}):
        for held_out in (False, True):
            for noise in sorted({r["noise"] for r in rows}):
                sub = [
                    r for r in rows
                    if r["sequence"] == name and r["held_out"] == held_out and r["noise"] == noise
                ]  # fmt: skip
                if sub:
                    summary.append(
                        [name, "held out" if held_out else "design", f"{noise:g}"]
                        + [f"{np.mean([r[k]['e3d'] for r in sub]):.4f}" for k in keys]
                        + [f"{np.mean([r[k]['seconds'] for r in sub]):.1f}" for k in keys]
                    )
    return [
        "Mean over seeds:",
        "",
        *table(["sequence", "seeds", "noise", *keys] + [f"{k} s" for k in keys], summary),
        "",
        "Per seed (* held out):",
        "",
        *table(header, body),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=("rotations", "e3d"))
    parser.add_argument("--sequences", nargs="+", default=list(SEQUENCES))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 10, 11, 12, 13])
    parser.add_argument("--noise", nargs="+", type=float, default=list(NOISES))
    parser.add_argument("--points", type=int, default=1_500)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--output-dir", type=Path, default=OUTPUT)
    parser.add_argument(
        "--estimators", nargs="+", default=list(ESTIMATORS), help="rotations: which to run"
    )
    parser.add_argument(
        "--merge",
        nargs="*",
        type=Path,
        default=[],
        help="rotations: JSON files of earlier runs whose rows of the other estimators join the "
        "table (the old estimators do not change when the new one does)",
    )
    args = parser.parse_args(argv)
    meta = provenance(sys.argv if argv is None else ["cameras.py", *argv])
    units = [
        (name, seed, noise, args.points)
        for name in args.sequences
        for seed in args.seeds
        for noise in args.noise
    ]
    if args.what == "rotations":
        units = [(*unit, tuple(args.estimators)) for unit in units]
        rows = [row for unit in parallel_map(rotation_unit, units, args.jobs) for row in unit]
        for path in args.merge:
            earlier = json.loads(path.read_text())["rows"]
            rows += [r for r in earlier if r["estimator"] not in args.estimators]
        meta["merged"] = [str(path) for path in args.merge]
        write_json(args.output_dir / "cameras_rotations.json", meta, rows=rows)
        write_markdown(
            args.output_dir / "cameras_rotations.md",
            "Camera rotations of every estimator, alone",
            meta,
            [
                f"Cells: mean rotation error (degrees, after one global alignment) / median "
                f"frame-to-frame error (degrees, mean over seeds) / largest frame-to-frame error "
                f"(degrees, over all seeds). {args.points:,} points (the body: 41 markers, 350 "
                f"frames), 60 frames (face3: 99). Design seeds {list(DESIGN_SEEDS)}; held out: "
                f"the others of {args.seeds}."
                + (
                    f" Rows of the estimators other than {', '.join(args.estimators)} come from "
                    f"{', '.join(meta['merged'])} (same sequences, same code for them)."
                    if args.merge
                    else ""
                ),
                *rotation_tables(rows, args.sequences, args.noise),
            ],
        )
    else:
        rows = parallel_map(e3d_unit, units, args.jobs)
        write_json(args.output_dir / "cameras_e3d.json", meta, rows=rows)
        write_markdown(
            args.output_dir / "cameras_e3d.md",
            "e3D with known and estimated rotations",
            meta,
            [
                f"`moju_core.reconstruct`, method moju, {args.points:,} points (the body: 41 "
                "markers). known: the true rotations; auto: the solver's own camera step "
                '(`rotations="auto"`, windowed rotations refined in the loop); plane G1 / '
                "G4: `moju_core.cameras.plane.plane_rotations` with 1 / 4 groups, passed as "
                '`rotations="known"` (not refined). Cells: e3D (per-frame Procrustes) and the '
                "mean rotation error in degrees; seconds include the plane estimate.",
                "",
                *e3d_tables(rows),
            ],
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
