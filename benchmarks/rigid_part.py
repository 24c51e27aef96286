"""The camera of an articulated body from its nearly rigid part: an oracle, and a robust fit.

    python benchmarks/rigid_part.py --seeds 0 1 2 10 11 12 13 --noise 0 0.03

The markers on an articulated body (``body-osc``, ``body-turn`` of
:mod:`moju_core.datasets.body`) move piecewise rigidly; the torso (the markers on the bones
that turn with the pelvis, the spine and the chest: about 40 % of them) bends by a few
degrees only. Per sequence:

* rotations alone: Tomasi-Kanade of every marker (``rigid``), the solver's own estimate
  (``auto``, :func:`moju_core.cameras.estimate_cameras`), Tomasi-Kanade of the torso's markers
  picked with the generator's bone labels (``torso (oracle)``), and the least-absolute-
  deviations rank-3 fit of every marker (``L1``: IRLS with weights ``1 / sqrt(r_p^2 +
  sigma^2)``, ``r_p`` a marker's RMS distance from the rank-3 subspace and ``sigma^2`` the
  noise variance of the spectrum, the plane estimator's cost at rank 3 with one group per
  marker), started from every marker and from the torso's (``L1 from torso``), with the cost
  each reaches: whether the robust cost itself tells the torso's subspace apart; and the
  maximum-likelihood rank-3 fit under a Cauchy model of the markers' distances with its scale
  estimated jointly (``Cauchy``: weights ``1 / (s^2 + r_p^2)``, ``s`` solving
  ``sum_p r_p^2 / (s^2 + r_p^2) = P / 2``; started from every marker and from each of 10
  k-means groups of trajectories, the start of least negative log-likelihood kept), a
  redescending cost that the outlying limbs cannot pull as far as they pull the L1 fit;
* e3D of ``moju_core.reconstruct`` with the true rotations, with ``rotations="auto"``, and
  with the oracle's rotations passed as known.

Cells of the rotation table: mean error after one global alignment / median frame-to-frame
error / largest frame-to-frame error, degrees. Writes ``rigid_part.{json,md}`` into
``--output-dir``.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from cameras import frame_to_frame_deg, load
from harness import RESULTS, parallel_map, provenance, table, write_json, write_markdown
from threadpoolctl import threadpool_limits

from moju_core import SolverParams, reconstruct
from moju_core.cameras import estimate_cameras
from moju_core.cameras.plane import group_labels
from moju_core.cameras.rigid import rigid_from_factor
from moju_core.datasets.body import JOINTS, marker_bones
from moju_core.metrics import evaluate, rotation_errors_deg
from moju_core.preprocessing import normalise
from moju_core.spectrum import noise_variance, spectrum

OUTPUT = RESULTS / "cameras"
MARKERS = 41
#: Bones (by child joint) that turn with the pelvis, the spine or the chest.
TORSO_BONES = ("spine", "left hip", "right hip", "chest", "neck", "left shoulder", "right shoulder")
ROTATIONS = ("rigid", "auto", "torso (oracle)", "L1", "L1 from torso", "Cauchy")
IRLS_ITERATIONS = 200
CAUCHY_GROUPS = 10


def torso_markers(n_markers: int = MARKERS) -> np.ndarray:
    """(P,) bool: the markers riding on :data:`TORSO_BONES`."""
    names = list(JOINTS)
    return np.isin(marker_bones(n_markers), [names.index(bone) for bone in TORSO_BONES])


def rank3_fit(W: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted rank-3 fit of the tracks (2F, P): the motion factor ``U_3 S_3^{1/2}`` (2F, 3)
    and every marker's mean squared distance from the subspace (P,)."""
    centred = W - ((W @ weights) / weights.sum())[:, None]
    u, s, _ = np.linalg.svd(centred * np.sqrt(weights), full_matrices=False)
    residual = centred - u[:, :3] @ (u[:, :3].T @ centred)
    return u[:, :3] * np.sqrt(s[:3]), np.einsum("ip,ip->p", residual, residual) / W.shape[0]


def reweighted_fit(
    W: np.ndarray,
    start: np.ndarray,
    weight: Callable[[np.ndarray], np.ndarray],
    tolerance: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Iteratively reweighted rank-3 fit from the marker weights ``start``: each step's weights
    are ``weight(squared distances)``, scaled to a largest of 1, until they change by less than
    ``tolerance``. The motion factor and the markers' squared distances at the end."""
    weights = start.astype(np.float64)
    for _ in range(IRLS_ITERATIONS):
        _, squared = rank3_fit(W, weights)
        updated = weight(squared)
        updated /= updated.max()
        converged = np.max(np.abs(updated - weights)) < tolerance
        weights = updated
        if converged:
            break
    return rank3_fit(W, weights)


def l1_fit(W: np.ndarray, start: np.ndarray, variance: float) -> tuple[np.ndarray, float]:
    """IRLS for ``sum_p sqrt(r_p^2 + sigma^2)`` from the marker weights ``start``: the motion
    factor and the cost reached."""
    factor, squared = reweighted_fit(
        W, start, lambda squared: 1.0 / np.sqrt(squared + variance + 1e-30), 1e-7
    )
    return factor, float(np.sqrt(squared + variance).sum())


def cauchy_scale(squared: np.ndarray) -> float:
    """Maximum-likelihood squared scale of a Cauchy model of distances whose squares are
    ``squared`` (P,): the root of ``sum_p r_p^2 / (s^2 + r_p^2) = P / 2``, by bisection in
    log s."""
    half = 0.5 * squared.size
    low, high = 1e-30, float(squared.max()) + 1e-30
    for _ in range(200):
        middle = np.sqrt(low * high)
        if np.sum(squared / (middle + squared)) > half:
            low = middle
        else:
            high = middle
    return float(np.sqrt(low * high))


def cauchy_fit(W: np.ndarray, start: np.ndarray) -> tuple[np.ndarray, float]:
    """IRLS for the Cauchy fit from the marker weights ``start``: the motion factor and the
    negative log-likelihood reached, ``sum_p log(1 + r_p^2 / s^2) + P log s``."""
    factor, squared = reweighted_fit(
        W, start, lambda squared: 1.0 / (cauchy_scale(squared) + squared), 1e-8
    )
    scale = cauchy_scale(squared)
    return factor, float(np.sum(np.log1p(squared / scale)) + 0.5 * squared.size * np.log(scale))


def best_cauchy_fit(W: np.ndarray, seed: int) -> np.ndarray:
    """The Cauchy fit of least negative log-likelihood over the starts: every marker, and
    each of :data:`CAUCHY_GROUPS` k-means groups of trajectories alone."""
    labels = group_labels(W, CAUCHY_GROUPS, seed=seed)
    starts = [np.ones(W.shape[1])] + [(labels == g) + 1e-3 for g in range(labels.max() + 1)]
    return min((cauchy_fit(W, start) for start in starts), key=lambda fit: fit[1])[0]


def unit(name: str, seed: int, noise: float) -> dict[str, Any]:
    data = load(name, seed, noise, MARKERS)
    W, _ = normalise(data.W)
    torso = torso_markers()
    variance = noise_variance(spectrum(W).singular, W.shape)
    row: dict[str, Any] = {"sequence": name, "seed": seed, "noise": noise, "costs": {}}
    with warnings.catch_warnings(), threadpool_limits(limits=1):
        warnings.simplefilter("ignore")
        estimates = {
            "rigid": rigid_from_factor(rank3_fit(W, np.ones(W.shape[1]))[0]),
            "auto": estimate_cameras(W, "auto", seed=seed).rotations,
            "torso (oracle)": rigid_from_factor(rank3_fit(W[:, torso], np.ones(torso.sum()))[0]),
        }
        for label, start in (("L1", np.ones(W.shape[1])), ("L1 from torso", torso + 1e-3)):
            factor, row["costs"][label] = l1_fit(W, start, variance)
            estimates[label] = rigid_from_factor(factor)
        estimates["Cauchy"] = rigid_from_factor(best_cauchy_fit(W, seed))
        for label, R in estimates.items():
            step = frame_to_frame_deg(R, data.rotations)
            row[label] = [
                float(rotation_errors_deg(R, data.rotations).mean()),
                float(np.median(step)), float(step.max()),
            ]  # fmt: skip
        for label, R in (
            ("known", data.rotations),
            ("auto", None),
            ("torso", estimates["torso (oracle)"]),
        ):
            params = SolverParams(
                method="moju", seed=seed, rotations="auto" if R is None else "known"
            )
            result = reconstruct(data.W, params, rotations=R)
            row[f"e3d {label}"] = evaluate(result.shapes, data.shapes)["e3d_procrustes"]
    print(
        f"{name} s{seed} n{noise}: "
        + " ".join(f"{k}={row[k][0]:.1f}" for k in ROTATIONS)
        + f" e3d known {row['e3d known']:.4f} "
        f"auto {row['e3d auto']:.4f} torso {row['e3d torso']:.4f}",
        flush=True,
    )
    return row


def tables(rows: list[dict[str, Any]]) -> list[str]:
    """One row per (sequence, seed, noise)."""
    header = ["sequence", "seed", "noise", *ROTATIONS, "L1 cost (from all / torso)",
              "e3D known", "e3D auto", "e3D torso (oracle)", "torso / known"]  # fmt: skip
    body = []
    for r in rows:
        cells = ["{:.1f} / {:.2f} / {:.1f}".format(*r[k]) for k in ROTATIONS]
        costs = f"{r['costs']['L1']:.4g} / {r['costs']['L1 from torso']:.4g}"
        e3d = [f"{r[k]:.4f}" for k in ("e3d known", "e3d auto", "e3d torso")]
        ratio = f"{r['e3d torso'] / r['e3d known']:.2f}"
        body.append([r["sequence"], r["seed"], f"{r['noise']:g}", *cells, costs, *e3d, ratio])
    return table(header, body)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequences", nargs="+", default=["body-osc", "body-turn"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 10, 11, 12, 13])
    parser.add_argument("--noise", nargs="+", type=float, default=[0.0, 0.03])
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--output-dir", type=Path, default=OUTPUT)
    args = parser.parse_args(argv)
    meta = provenance(sys.argv if argv is None else ["rigid_part.py", *argv])
    units = [(n, s, x) for n in args.sequences for s in args.seeds for x in args.noise]
    rows = parallel_map(unit, units, args.jobs)
    write_json(args.output_dir / "rigid_part.json", meta, rows=rows)
    write_markdown(
        args.output_dir / "rigid_part.md",
        "The camera of an articulated body from its nearly rigid part",
        meta,
        [
            f"{MARKERS} markers, 350 frames. Rotation cells: mean error after one global "
            "alignment / median frame-to-frame error / largest frame-to-frame error, degrees. "
            "e3D: per-frame Procrustes; the oracle's rotations passed as known.",
            "",
            *tables(rows),
        ],
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
