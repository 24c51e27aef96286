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
``plane+trajectory`` is ``plane G4`` refined by :func:`trajectory_rotations` (alternation with
a DCT trajectory basis whose size is cross-validated over left-out frames; measured, not kept).

``e3d``: ``moju_core.reconstruct`` with the true rotations, with ``rotations="auto"`` (which
refines windowed rotations in the loop), and with the plane rotations (``plane G1``,
``plane G4``, ``plane+trajectory``) passed as ``rotations="known"`` (not refined: the plane
estimator is not wired into ``"auto"``); ``--solves`` picks which of them run.

``rule``: whether the short-time rigidity (:func:`moju_core.cameras.windowed.
short_time_rigidity`, the misfit of every three frames to a rigid shape) tells when the plane
rotations (``plane G4``) beat ``"auto"``'s: both misfits, unexplained energy over the total,
noise included (white noise adds the same share to both, so their order does not depend on
the noise estimate), and the rotation errors; the rule "the plane where its misfit is smaller"
is scored against the errors. Measured, not wired.

Seeds 0-2 were used to design the estimator; 10-13 are held out. Writes
``cameras_rotations.{json,md}`` / ``cameras_e3d.{json,md}`` / ``cameras_rule.{json,md}``
into ``--output-dir``.
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
from moju_core.cameras.refinement import fit_rotations_to_shapes, project_to_stiefel
from moju_core.cameras.windowed import WINDOW_LENGTHS, RowGram, short_time_rigidity
from moju_core.datasets import make_sequence
from moju_core.metrics import evaluate, rotation_errors_deg
from moju_core.preprocessing import normalise
from moju_core.pta import dct_basis, trajectory_system
from moju_core.spectrum import noise_variance, spectrum

OUTPUT = RESULTS / "cameras"
SEQUENCES = (
    "flag-osc", "flag-turn", "bumps-osc", "roll-osc", "cloth", "body-osc", "body-turn", "face3",
)  # fmt: skip
DESIGN_SEEDS = (0, 1, 2)
NOISES = (0.0, 0.01, 0.03, 0.055)
ESTIMATORS = (
    "rigid", "windowed", "intersection", "auto", "plane G1", "plane G4", "plane G10",
    "plane+trajectory",
)  # fmt: skip
#: The trajectory basis size of the last ``plane+trajectory`` estimate.
CHOSEN_BASES = [0]
SOLVES = ("known", "auto", "plane G1", "plane G4", "plane+trajectory")


def load(name: str, seed: int, noise: float, n_points: int):
    """A stress sequence; the body has its 41 markers whatever ``n_points`` says."""
    points = 41 if name.startswith("body") else n_points
    return make_sequence(name, n_points=points, noise=noise, seed=seed)


def _complete(rows: np.ndarray) -> np.ndarray:
    rows = project_to_stiefel(rows)
    return np.concatenate([rows, np.cross(rows[:, 0], rows[:, 1])[:, None]], axis=1)


# The trajectory refinement of the plane rotations (the ``plane+trajectory`` row). Measured
# and not kept in moju_core (docs/cameras.md, "Tried and dropped"). From starting rotations
# alternate (1) the point trajectories in the first K DCT vectors given the rotations
# (Akhter et al.'s point trajectory approach, ``W = M A`` with ``M = R (Theta kron I_3)`` of
# shape (2F, 3K), least squares for all P points at once) and (2) the rotations given the
# shapes (:func:`fit_rotations_to_shapes`). K is chosen by K-fold cross-validation over frames:
# every CV_FOLDS-th frame is left out, the alternation runs on the others, a left-out frame is
# predicted by the trajectories evaluated there seen through the one rotation that fits it
# best, and the K of least prediction error is used; the tracks' noise enters through that
# error. Costs per alternation step: an SVD of the (2F, 3K) system O(F K^2), O(F K P) for the
# coefficients and shapes, O(F P) for the rotation fit; the choice of K repeats the
# alternation CV_FOLDS + 1 times per candidate K. Nothing grows with P^2 or F^2.

#: Folds of the cross-validation over frames (every fifth frame left out in turn).
CV_FOLDS = 5

#: Alternation steps (trajectories, then rotations) per fit.
ITERATIONS = 10


def candidate_bases(n_frames: int, n_folds: int = CV_FOLDS) -> list[int]:
    """Sizes K of the trajectory basis that cross-validation compares: 2, 3, 4, 6, 8, ...
    (about 1.4 times apart) up to what the training frames of one fold determine
    (``3K <= 2 F_train``, with room: ``3K <= F_train``)."""
    train = n_frames - -(-n_frames // n_folds)
    largest = max(2, train // 3)
    grid, k = [], 2.0
    while round(k) <= largest:
        if not grid or round(k) != grid[-1]:
            grid.append(round(k))
        k *= np.sqrt(2.0)
    return grid


def _coefficients(tracks: np.ndarray, rotations: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Least-squares trajectory coefficients A (3K, P) of ``W = M A``."""
    n_frames, _, n_points = tracks.shape
    system = trajectory_system(rotations, basis)
    u, s, vt = np.linalg.svd(system, full_matrices=False)
    keep = s > 1e-10 * s[0]
    return (vt[keep].T / s[keep]) @ (u[:, keep].T @ tracks.reshape(2 * n_frames, n_points))


def _shapes(basis: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """Shapes (F', 3, P) of trajectory coefficients (3K, P) at the frames of ``basis`` (F', K)."""
    n_bases = basis.shape[1]
    n_points = coefficients.shape[1]
    flat = basis @ coefficients.reshape(n_bases, 3 * n_points)
    return flat.reshape(basis.shape[0], 3, n_points)


def alternate(
    tracks: np.ndarray, rotations: np.ndarray, basis: np.ndarray, iterations: int = ITERATIONS
) -> tuple[np.ndarray, np.ndarray]:
    """Alternate trajectories and rotations from the given rotations.

    Parameters
    ----------
    tracks : ndarray of shape (F, 2, P)
        Centred tracks.
    rotations : ndarray of shape (F, 2, 3)
        Starting rotations.
    basis : ndarray of shape (F, K)
        Trajectory basis at these frames (rows of :func:`moju_core.pta.dct_basis`).

    Returns
    -------
    rotations : ndarray of shape (F, 2, 3)
    coefficients : ndarray of shape (3K, P)
        Trajectory coefficients under the returned rotations.
    """
    for _ in range(iterations):
        shapes = _shapes(basis, _coefficients(tracks, rotations, basis))
        rotations = fit_rotations_to_shapes(rotations, tracks, shapes)
    return rotations, _coefficients(tracks, rotations, basis)


def cross_validation_error(
    tracks: np.ndarray, rotations: np.ndarray, n_bases: int, n_folds: int = CV_FOLDS
) -> float:
    """Mean squared error of left-out frames predicted with ``n_bases`` trajectory bases.

    Fold j leaves out the frames ``f = j mod n_folds``; the alternation runs on the others from
    ``rotations``; each left-out frame's shape is the trajectories evaluated there, and its
    rotation the one that projects that shape best onto its tracks (from its starting rotation).

    Returns
    -------
    float
        Squared error per entry of the tracks, in their squared units.
    """
    n_frames = tracks.shape[0]
    basis = dct_basis(n_frames, n_bases)
    folds = np.arange(n_frames) % n_folds
    error = 0.0
    for fold in range(n_folds):
        test = folds == fold
        _, coefficients = alternate(tracks[~test], rotations[~test], basis[~test])
        shapes = _shapes(basis[test], coefficients)
        fitted = fit_rotations_to_shapes(rotations[test], tracks[test], shapes)
        error += float(np.sum((tracks[test] - fitted @ shapes) ** 2))
    return error / tracks.size


def trajectory_rotations(
    W: np.ndarray, rotations: np.ndarray, n_bases: int | None = None
) -> tuple[np.ndarray, int]:
    """Rotations refined by alternation with a trajectory basis of cross-validated size.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Tracks (translations are removed here), F >= 2 CV_FOLDS.
    rotations : ndarray of shape (F, 2, 3)
        Starting rotations (rows orthonormal), e.g. the plane estimate.
    n_bases : int, optional
        Size K of the trajectory basis; chosen by :func:`cross_validation_error` over
        :func:`candidate_bases` when omitted.

    Returns
    -------
    rotations : ndarray of shape (F, 2, 3)
        Rows orthonormal, in the starting rotations' global frame.
    n_bases : int
        The K used.
    """
    W = np.asarray(W, dtype=np.float64)
    n_frames = W.shape[0] // 2
    tracks = (W - W.mean(axis=1, keepdims=True)).reshape(n_frames, 2, -1)
    if n_bases is None:
        grid = candidate_bases(n_frames)
        errors = [cross_validation_error(tracks, rotations, k) for k in grid]
        n_bases = grid[int(np.argmin(errors))]
    refined, _ = alternate(tracks, rotations, dct_basis(n_frames, n_bases))
    return refined, int(n_bases)


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
    """Rotations of centred tracks by one of :data:`ESTIMATORS` (``plane+trajectory``: the
    trajectory basis size chosen is stored in ``CHOSEN_BASES``)."""
    if name.startswith("plane"):
        variance = noise_variance(spectrum(W).singular, W.shape)
        if name == "plane+trajectory":
            start = plane_rotations(W, n_groups=4, noise_variance=variance, seed=seed)
            rotations, CHOSEN_BASES[0] = trajectory_rotations(W, start)
            return rotations
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
            if estimator == "plane+trajectory":
                rows[-1]["n_bases"] = CHOSEN_BASES[0]
    print(
        f"{name} s{seed} n{noise}: "
        + " ".join(f"{r['estimator']}={r['rotation_error_deg']:.1f}" for r in rows),
        flush=True,
    )
    return rows


def rule_unit(name: str, seed: int, noise: float, n_points: int) -> dict[str, Any]:
    """The short-time rigidity of ``"auto"``'s rotations and of ``plane G4``'s, with their
    mean rotation errors (degrees), on one stress sequence."""
    data = load(name, seed, noise, n_points)
    W, _ = normalise(data.W)
    gram = RowGram(W, max(WINDOW_LENGTHS))
    row: dict[str, Any] = {"sequence": name, "seed": seed, "noise": noise}
    with threadpool_limits(limits=1), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        auto = estimate_cameras(W, "auto", seed=seed)
        row["auto_source"] = auto.source
        for estimator, R in (("auto", auto.rotations), ("plane G4", estimate(W, "plane G4", seed))):
            row[f"{estimator} misfit"] = short_time_rigidity(gram, R[:, :2])
            row[f"{estimator} error"] = float(rotation_errors_deg(R, data.rotations).mean())
    smaller = row["plane G4 misfit"] < row["auto misfit"]
    row["rule right"] = bool(smaller == (row["plane G4 error"] < row["auto error"]))
    print(name, seed, noise, row["rule right"], flush=True)
    return row


def rule_tables(rows: list[dict[str, Any]]) -> list[str]:
    """Per case: the two misfits and errors and whether the rule chose the better; then the
    count of right choices per sequence."""
    header = ["sequence", "seed", "noise", "auto source", "auto misfit", "plane misfit"]
    header += ["auto error (deg)", "plane error (deg)", "rule right"]
    lines = [
        [r["sequence"], r["seed"], r["noise"], r["auto_source"], f"{r['auto misfit']:.5f}",
         f"{r['plane G4 misfit']:.5f}", f"{r['auto error']:.1f}", f"{r['plane G4 error']:.1f}",
         "yes" if r["rule right"] else "no"]
        for r in rows
    ]  # fmt: skip
    counts = [
        [name, sum(r["rule right"] for r in rows if r["sequence"] == name),
         sum(r["sequence"] == name for r in rows)]
        for name in dict.fromkeys(r["sequence"] for r in rows)
    ]  # fmt: skip
    return [*table(header, lines), "", *table(["sequence", "right", "cases"], counts)]


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


def e3d_unit(
    name: str, seed: int, noise: float, n_points: int, solves: tuple[str, ...] = SOLVES
) -> dict[str, Any]:
    data = load(name, seed, noise, n_points)
    W, _ = normalise(data.W)
    row: dict[str, Any] = {
        "sequence": name, "seed": seed, "noise": noise, "held_out": seed not in DESIGN_SEEDS,
        "n_points": data.n_points, "n_frames": data.n_frames,
    }  # fmt: skip
    for key in solves:
        if key in ("known", "auto"):
            row[key] = _solve(data, data.rotations if key == "known" else None, seed)
            continue
        start = time.perf_counter()
        with threadpool_limits(limits=1):
            R = estimate(W, key, seed)
        seconds = time.perf_counter() - start
        solved = _solve(data, R, seed)
        solved["seconds"] += seconds
        solved["rotation_error_deg"] = float(rotation_errors_deg(R, data.rotations).mean())
        step = frame_to_frame_deg(R, data.rotations)
        solved["f2f_median_deg"], solved["f2f_max_deg"] = float(np.median(step)), float(step.max())
        if key == "plane+trajectory":
            solved["n_bases"] = CHOSEN_BASES[0]
        row[key] = solved
    print(
        f"{name} s{seed} n{noise}: " + " ".join(f"{k} {row[k]['e3d']:.4f}" for k in solves),
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
    keys = [k for k in SOLVES if k in rows[0]]
    ratios = [k for k in keys if k.startswith("plane")] if "known" in keys else []
    header = ["sequence", "seed", "noise"] + [f"{k} e3D (rot deg)" for k in keys]
    header += [f"{k} / known" for k in ratios]
    body = [
        [r["sequence"], f"{r['seed']}{'*' if r['held_out'] else ''}", f"{r['noise']:g}"]
        + [f"{r[k]['e3d']:.4f} ({r[k]['rotation_error_deg']:.1f})" for k in keys]
        + [f"{r[k]['e3d'] / r['known']['e3d']:.2f}" for k in ratios]
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
    parser.add_argument("what", choices=("rotations", "e3d", "rule"))
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
        "--solves", nargs="+", default=list(SOLVES), choices=SOLVES, help="e3d: which to run"
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
    if args.what == "rule":
        rows = parallel_map(rule_unit, units, args.jobs)
        write_json(args.output_dir / "cameras_rule.json", meta, rows=rows)
        write_markdown(
            args.output_dir / "cameras_rule.md",
            "Does the short-time rigidity tell when the plane rotations are better?",
            meta,
            [
                "Misfit: `short_time_rigidity` of the rotations (unexplained share of the "
                "tracks' energy over every three frames, noise included); error: mean rotation "
                "error (degrees). The rule takes the plane where its misfit is smaller; "
                "'rule right' when that is the estimate with the smaller error.",
                "",
                *rule_tables(rows),
            ],
        )
        return 0
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
        rows = parallel_map(e3d_unit, [(*unit, tuple(args.solves)) for unit in units], args.jobs)
        write_json(args.output_dir / "cameras_e3d.json", meta, rows=rows)
        write_markdown(
            args.output_dir / "cameras_e3d.md",
            "e3D with known and estimated rotations",
            meta,
            [
                f"`moju_core.reconstruct`, method moju, {args.points:,} points (the body: 41 "
                "markers). known: the true rotations; auto: the solver's own camera step "
                '(`rotations="auto"`, windowed rotations refined in the loop); plane G1 / '
                "G4: `moju_core.cameras.plane.plane_rotations` with 1 / 4 groups; "
                "plane+trajectory: plane G4 refined by `trajectory_rotations` of "
                "benchmarks/cameras.py; the plane rotations passed as "
                '`rotations="known"` (not refined). Cells: e3D (per-frame Procrustes) and the '
                "mean rotation error in degrees; seconds include the plane estimate.",
                "",
                *e3d_tables(rows),
            ],
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
