"""Two routes the surface prior does not take, measured on rendered footage: the object's own
motion, and hidden points moved by their neighbours.

``bundle``: the prior gives every image's shape from that image alone; the object also turns
by 5-30 degrees in front of a perspective camera, which a rigid structure-from-motion fit
turns into depth. From the anchors' prior shapes, a rigid bundle adjustment (one shape, one
pose per image) minimises the reprojection error on the viewing rays (standard deviation
``0.5 px / f`` from tracks, ``0.05 px / f`` from perfect tracks) plus the depths' distance to
the prior's (standard deviation ``sd`` of the mean depth 1), by scipy's sparse trust-region
least squares from the prior's shapes posed rigidly (``posed``: the Procrustes mean shape of
the prior's images, put back into each image by its rigid motion). Scores: the anchors' e3D
over their seen entries (per-image scale and Procrustes), with the best single rigid shape
of the truth for reference (an oracle).

``fill``: a hidden entry of the prior is filled from the nearest images that see it, moved by
the rigid motion of the points both images have (``global``, the solver's rule); here also
by the rigid motion of its ``k`` nearest such points only (``k10`` ... ``k300``). Scores: e3D
over every entry of every image (the footage benchmark's first score), the prior alone.

    PYTHONPATH=.:benchmarks nice python benchmarks/motion_and_fill.py bundle \\
        --scenes cloth:0 curl:0 curl:1 crease:0 crease:1 --held-out cloth:11 crease:22 curl:21
    PYTHONPATH=.:benchmarks nice python benchmarks/motion_and_fill.py fill \\
        --scenes crease:1 cloth:0 --held-out crease:22

Neither route is used by the solver; the notebook says why.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
import scipy.sparse as sp
from dense_stage import N_ANCHOR, RIGIDITY, rigid_depths, scene_rays
from dense_stage import K as NEIGHBOURS
from footage import visible_e3d
from harness import RESULTS, provenance, table, write_json, write_markdown
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

import moju_core.perspective as perspective
from moju_core.datasets.totem import scaled_e3d
from moju_core.priors.cut_off_groups import hold_cut_off_groups
from moju_core.priors.dense_depth import homogeneous
from moju_core.priors.key_images import solve_by_key_images
from moju_core.priors.max_depth import max_depth_shapes
from moju_core.priors.neighbour_graph import neighbour_edges, spread_anchors

OUT = RESULTS / "surface_prior"
DEPTH_SDS = (0.01, 0.03, 0.1)
FILL_KS = (10, 30, 100, 300)
TRACK_PX = {"tracks": 0.5, "perfect": 0.05}


def batched_rigid(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (n, 3, 3) and shifts (n, 3) taking ``source`` (n, k, 3) closest to
    ``target`` (n, k, 3) (Kabsch, no reflection)."""
    source_mean, target_mean = source.mean(axis=1), target.mean(axis=1)
    covariance = np.einsum(
        "nki,nkj->nij", source - source_mean[:, None], target - target_mean[:, None]
    )
    u, _, vt = np.linalg.svd(covariance)
    u[:, :, 2] *= np.sign(np.linalg.det(u @ vt))[:, None]
    rotation = np.transpose(u @ vt, (0, 2, 1))
    return rotation, target_mean - np.einsum("nij,nj->ni", rotation, source_mean)


def posed_mean(shapes: np.ndarray, seen: np.ndarray, rounds: int = 5) -> tuple[np.ndarray, ...]:
    """The rigid model closest to ``shapes`` (F, A, 3) over ``seen`` (F, A): rotation
    vectors (F, 3), shifts (F, 3) and the mean shape (A, 3) in the best-seen image's frame."""
    mean = np.where(
        seen[np.argmax(seen.sum(axis=1))][:, None], shapes[np.argmax(seen.sum(axis=1))], np.nan
    )
    for _ in range(rounds):
        rotations, shifts = [], []
        aligned = np.full_like(shapes, np.nan)
        for f in range(len(shapes)):
            both = seen[f] & np.isfinite(mean[:, 0])
            rotation, shift = batched_rigid(mean[both][None], shapes[f, both][None])
            rotations.append(rotation[0])
            shifts.append(shift[0])
            aligned[f, seen[f]] = (shapes[f, seen[f]] - shift[0]) @ rotation[0]
        mean = np.nanmean(aligned, axis=0)
    mean = np.where(np.isfinite(mean), mean, np.nanmean(mean, axis=0))
    return Rotation.from_matrix(np.array(rotations)).as_rotvec(), np.array(shifts), mean


def _camera_points(x: np.ndarray, n_frames: int, n_points: int) -> np.ndarray:
    poses = x[: 6 * n_frames].reshape(n_frames, 6)
    mean = x[6 * n_frames :].reshape(n_points, 3)
    rotations = Rotation.from_rotvec(poses[:, :3]).as_matrix()
    return np.einsum("fij,aj->fai", rotations, mean) + poses[:, None, 3:]


def _jacobian_pattern(seen: np.ndarray) -> sp.csr_matrix:
    frames, points = np.nonzero(seen)
    n_frames, n_points = seen.shape
    rows, cols = [], []
    for block in range(3):  # x and y on the ray, depth
        row = block * len(frames) + np.arange(len(frames))
        rows += [row] * 9
        cols += [6 * frames + j for j in range(6)] + [
            6 * n_frames + 3 * points + d for d in range(3)
        ]
    rows_, cols_ = np.concatenate(rows), np.concatenate(cols)
    shape = (3 * len(frames), 6 * n_frames + 3 * n_points)
    return sp.csr_matrix((np.ones(len(rows_)), (rows_, cols_)), shape=shape)


def posed_start(rays: np.ndarray, seen: np.ndarray, depths: np.ndarray) -> np.ndarray:
    """The bundle adjustment's start: :func:`posed_mean` of the shapes of ``depths`` (F, A),
    packed as the unknowns (6 F + 3 A,)."""
    rotvecs, shifts, mean = posed_mean(np.nan_to_num(depths)[..., None] * homogeneous(rays), seen)
    return np.concatenate([np.hstack([rotvecs, shifts]).ravel(), mean.ravel()])


def rigid_bundle(rays, seen, depths, x0, ray_sd, depth_sd) -> np.ndarray:
    """Camera-frame points (F, A, 3) of the rigid bundle adjustment started from ``x0``."""
    n_frames, n_points, _ = rays.shape
    frames, points = np.nonzero(seen)
    observed, prior = rays[frames, points], depths[frames, points]

    def residuals(x: np.ndarray) -> np.ndarray:
        X = _camera_points(x, n_frames, n_points)[frames, points]
        on_ray = (X[:, :2] / X[:, 2:] - observed) / ray_sd
        return np.concatenate([on_ray[:, 0], on_ray[:, 1], (X[:, 2] - prior) / depth_sd])

    fit = least_squares(
        residuals, x0, jac_sparsity=_jacobian_pattern(seen), x_scale="jac", max_nfev=60
    )
    return _camera_points(fit.x, n_frames, n_points)


def bundle_row(rays, seen, truth, ray_sd: float) -> dict[str, Any]:
    """Anchors' e3D of the prior, its rigid pose, the bundle adjustments and the oracle;
    ``ray_sd`` the tracks' standard deviation on the rays (pixels over the focal length)."""
    anchors = spread_anchors(rays, seen, n_anchor=N_ANCHOR, seed=0)
    r, s, true = rays[:, anchors], seen[:, anchors], truth[:, anchors]
    edges = neighbour_edges(r, s, k=NEIGHBOURS)
    cone = solve_by_key_images(r, s, edges, rigidity=RIGIDITY, outlier_price=np.inf)
    depths = hold_cut_off_groups(r, s, edges, cone.depths, cone.lengths, cone.shrink)
    placed = s & np.isfinite(depths)
    depths = np.where(placed, depths, np.nan) / np.nanmean(np.where(placed, depths, np.nan))
    points = homogeneous(r)
    row = {
        "prior": visible_e3d(np.nan_to_num(depths[..., None] * points), true, placed),
        "rigid truth (oracle)": visible_e3d(
            rigid_depths(r, true)[..., None] * points, true, placed
        ),
    }
    x0 = posed_start(r, placed, depths)
    row["posed"] = visible_e3d(_camera_points(x0, *r.shape[:2]), true, placed)
    for depth_sd in DEPTH_SDS:
        bundle = rigid_bundle(r, placed, depths, x0, ray_sd, depth_sd)
        row[f"bundle sd {depth_sd:g}"] = visible_e3d(bundle, true, placed)
    return row


def local_fill(shapes: np.ndarray, known: np.ndarray, k: int) -> np.ndarray:
    """``perspective._fill_hidden`` with each source moved by the rigid motion of the ``k``
    points nearest to it (in the source image) among those both images have."""
    filled = shapes.copy()
    sources = perspective._nearest_known(known, perspective.FILL_SOURCES)
    for frame in range(known.shape[0]):
        todo = np.flatnonzero(~known[frame] & (sources[0, frame] >= 0))
        moved = np.full((sources.shape[0], todo.size, 3), np.nan)
        of_frame = sources[:, frame, todo]
        for source in np.unique(of_frame[of_frame >= 0]):
            both = np.flatnonzero(known[frame] & known[source])
            rank, column = np.nonzero(of_frame == source)
            moving = shapes[source, todo[column]]
            count = min(k, both.size)
            near = (
                cKDTree(shapes[source, both]).query(moving, k=count)[1].reshape(len(moving), count)
            )
            rotation, shift = batched_rigid(shapes[source, both[near]], shapes[frame, both[near]])
            moved[rank, column] = np.einsum("nij,nj->ni", rotation, moving) + shift
        if todo.size:
            filled[frame, todo] = np.nanmedian(moved, axis=0)
    return filled


def fill_row(rays, seen, truth) -> dict[str, Any]:
    """Every entry's e3D of the prior with each way of filling its hidden entries."""
    fit = max_depth_shapes(rays, seen, seed=0)
    placed = np.isfinite(fit.depths)
    shapes = fit.depths[..., None] * homogeneous(rays)

    def every_entry(estimate: np.ndarray) -> float:
        pairs = zip(estimate, truth, strict=True)
        return float(np.mean([scaled_e3d(e[None], t[None]) for e, t in pairs]))

    row = {
        "hidden": float(1.0 - placed.mean()),
        "global": every_entry(perspective._fill_hidden(shapes, placed)),
    }
    for k in FILL_KS:
        row[f"k{k}"] = every_entry(local_fill(shapes, placed, k))
    return row


def run_scene(kind: str, seed: int, experiment: str) -> list[dict[str, Any]]:
    """Rows (tracks, perfect) of one scene."""
    args = argparse.Namespace(frames=30, width=640, height=480, mesh=6000)
    rows = []
    for source, rays, seen, truth, focal in scene_rays(kind, seed, args):
        if experiment == "bundle":
            scores = bundle_row(rays, seen, truth, TRACK_PX[source] / focal)
        else:
            scores = fill_row(rays, seen, truth)
        row = {"kind": kind, "seed": seed, "source": source, **scores}
        print(row, flush=True)
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiment", choices=("bundle", "fill"))
    parser.add_argument("--scenes", nargs="*", default=[], help="design scenes, KIND:SEED")
    parser.add_argument("--held-out", nargs="*", default=[], help="held-out scenes, KIND:SEED")
    args = parser.parse_args()
    meta = provenance()
    splits: dict[str, list[dict[str, Any]]] = {}
    for split, scenes in (("design", args.scenes), ("held-out", args.held_out)):
        for scene in scenes:
            kind, seed = scene.split(":")
            splits.setdefault(split, []).extend(run_scene(kind, int(seed), args.experiment))
            write(args.experiment, meta, splits)


def write(experiment: str, meta: dict[str, Any], splits: dict[str, list[dict[str, Any]]]) -> None:
    """JSON and one markdown table per split."""
    name = f"motion_and_fill_{experiment}"
    write_json(OUT / f"{name}.json", meta, splits=splits)
    body: list[str] = []
    for split, rows in splits.items():
        scores = [k for k in rows[0] if k not in ("kind", "seed", "source")]
        lines = [
            [r["kind"], r["seed"], r["source"]] + [f"{r[k]:.4f}" for k in scores] for r in rows
        ]
        body += [f"## {split}", "", *table(["kind", "seed", "tracks", *scores], lines), ""]
    title = (
        "The object's motion (rigid bundle adjustment)"
        if experiment == "bundle"
        else "Hidden entries moved by their neighbours"
    )
    write_markdown(OUT / f"{name}.md", title, meta, body)


if __name__ == "__main__":
    main()
