"""The surface prior's dense stage on rendered footage, and where its consistency rounds stop.

For each scene (rendered and tracked as in ``benchmarks/footage.py``) the cone program is
solved once on the anchors; the dense stage is then run three ways from the same anchor
depths, and the prior alone is scored over the seen entries (``visible_e3d``, per-frame scale
and Procrustes):

* ``interpolation``: local planes through the anchors' inverse depths (the default);
* ``refinement``: the same, then 60 iterations of the first-order maximum-depth push under
  the dense edges' bounds (``refine_iter=60``);
* ``two-sided``: the same iterations without the push, every dense edge pulled to its bound
  from both sides (a dense analogue of the consistency rounds).

``--oracle-start`` runs the anchors' consistency rounds from the true depths and from the
best single rigid shape of the truth posed in every frame: the cost the program reaches
from each against the cost it reaches from its own start, with the anchors' e3D of each. It
is a diagnostic (it reads the truth), not a method. ``--smoothed-start`` does the same from
two starts made from the tracks alone, the plain program's depths smoothed in each image:
``bent`` (the polynomial of degree 2 in ``(x', y')`` closest to the inverse depths: a plane
and one bend) and ``local`` (each anchor's inverse depth replaced by the weighted plane
through its 8 nearest anchors, the interpolation's local fit).

    PYTHONPATH=. nice python benchmarks/dense_stage.py --seeds 0 1 2 10 11 12 \\
        --held-out 20 21 22 30 31 32
    PYTHONPATH=. nice python benchmarks/dense_stage.py --seeds 11 --held-out --oracle-start \\
        --tag _oracle_start
    PYTHONPATH=. nice python benchmarks/dense_stage.py --seeds 20 --held-out --oracle-start \\
        --tag _oracle_start_20
    PYTHONPATH=. nice python benchmarks/dense_stage.py --seeds 0 1 2 11 20 --held-out \\
        --smoothed-start --tag _smoothed_start
    PYTHONPATH=. nice python benchmarks/dense_stage.py --seeds --held-out 21 22 30 \\
        --smoothed-start --tag _smoothed_start_held_out_a  # and 31 32, _held_out_b
    PYTHONPATH=.:benchmarks nice python benchmarks/dense_stage.py --seeds 0 1 2 --held-out \\
        --lengths --tag _lengths_design
    PYTHONPATH=.:benchmarks nice python benchmarks/dense_stage.py --seeds \\
        --held-out 11 20 21 22 --lengths --tag _lengths_held_out

``--lengths`` measures the edge lengths' part in the anchors' error: the joint program with
its lengths scaled over the edges (the program of MDH) and over the (image, edge) pairs, how far
each puts the lengths of rarely and often seen edges from the truth's, and single images
solved with the truth's lengths (an oracle).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np
from footage import procrustes_mean, scene_video, visible_e3d
from harness import RESULTS, provenance, table, write_json, write_markdown
from tracking import perfect_tracks

import moju_core.priors.cone_program as cone_program
from moju_core.datasets.footage_scenes import FOOTAGE_KINDS
from moju_core.footage.tracking import track_frames
from moju_core.priors import dense_depth
from moju_core.priors.cut_off_groups import hold_cut_off_groups
from moju_core.priors.key_images import solve_by_key_images
from moju_core.priors.max_depth import _scaled_shapes
from moju_core.priors.neighbour_graph import neighbour_edges, spread_anchors
from moju_core.priors.smoothed_starts import smoothed_start_depths

OUT = RESULTS / "surface_prior"
N_ANCHOR, K, RIGIDITY, REFINE_ITER = 200, 8, 30.0, 60


def _two_sided_image(q, d, free, i, j, bounds, n_iter, push, n_project):
    """``dense_depth._refine_image`` with every edge pulled to its bound from both sides."""
    n_points = d.size
    qi, qj = q[i], q[j]
    for _ in range(n_iter * n_project):
        diff = d[i, None] * qi - d[j, None] * qj
        length = np.linalg.norm(diff, axis=1)
        u = diff / np.maximum(length, 1e-300)[:, None]
        gi, gj = np.einsum("ek,ek->e", u, qi), -np.einsum("ek,ek->e", u, qj)
        step = (length - bounds) / np.maximum(gi**2 + gj**2, 1e-2)
        delta = -np.bincount(i, step * gi, n_points) - np.bincount(j, step * gj, n_points)
        count = np.bincount(i, minlength=n_points) + np.bincount(j, minlength=n_points)
        d = np.where(free, d + np.clip(delta / np.maximum(count, 1.0), -0.05 * d, 0.05 * d), d)
    diff = d[i, None] * qi - d[j, None] * qj
    return d, np.linalg.norm(diff, axis=1) - bounds


def dense_variants(rays, seen, anchors, anchor_depths) -> dict[str, np.ndarray]:
    """Depths (F, P) of every point by the three dense stages, from the same anchor depths."""
    interpolated = dense_depth.interpolate_depths(rays, seen, anchors, anchor_depths)
    edges = neighbour_edges(rays, seen, k=K)
    out = {"interpolation": interpolated}
    out["refinement"] = dense_depth.refine_depths(
        rays, seen, edges, interpolated, anchors, n_iter=REFINE_ITER
    )[0]
    original = dense_depth._refine_image
    dense_depth._refine_image = _two_sided_image
    try:
        out["two-sided"] = dense_depth.refine_depths(
            rays, seen, edges, interpolated, anchors, n_iter=REFINE_ITER, push=0.0
        )[0]
    finally:
        dense_depth._refine_image = original
    return out


def rigid_depths(rays: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Depths (F, A) along the rays of the best single rigid shape of ``truth`` (F, A, 3):
    the generalised Procrustes mean of the true frames, scaled and posed onto each frame."""
    centred = truth - truth.mean(axis=1, keepdims=True)
    mean = procrustes_mean(truth)
    posed = np.empty_like(truth)
    for f in range(truth.shape[0]):
        u, s, vt = np.linalg.svd(centred[f].T @ mean)
        posed[f] = (s.sum() / np.sum(mean**2)) * mean @ (u @ vt).T + truth[f].mean(axis=0)
    q = dense_depth.homogeneous(rays)
    return np.sum(posed * q, axis=2) / np.sum(q * q, axis=2)  # nearest points of the rays


def oracle_starts(rays, first, truth) -> dict[str, np.ndarray]:
    """Starts (F, A) read from the truth (F, A, 3): its depths, and :func:`rigid_depths`."""
    return {"true start": truth[..., 2], "rigid start": rigid_depths(rays, truth)}


def smoothed_starts(rays, first, truth) -> dict[str, np.ndarray]:
    """Starts (F, A) from the plain program's depths ``first`` (F, A), smoothed per image."""
    bent, local = smoothed_start_depths(rays, first)
    return {"bent start": bent, "local start": local}


def rounds_from_starts(rays, seen, edges, truth, make_starts) -> dict[str, float]:
    """Costs and anchors' e3D of the consistency rounds (all images jointly) from their own
    start and from each start of ``make_starts(rays, first_depths, truth)``; ``truth``
    (F, A, 3) the anchors' true 3D paths."""
    original = cone_program._consistency_rounds
    costs: dict[str, float] = {}
    start: dict[str, np.ndarray] = {}

    def rounds(program, cost, best, own, status, *, n_rounds, tol):
        first = cone_program._unpack(program.pairs, best)[0]
        start.setdefault("starts", make_starts(rays, first, truth))
        if "label" in start:
            given = start["starts"][start["label"]][program.pairs.constrained]
            own = given * np.mean(best[program.depths]) / np.mean(given)
        result = original(program, cost, best, own, status, n_rounds=n_rounds, tol=tol)
        costs["cost"] = float(cost @ result[1])
        return result

    cone_program._consistency_rounds = rounds
    out: dict[str, float] = {}
    try:
        label = "own start"
        while True:  # the own start's solve makes the others (from its first round)
            sol = cone_program.solve_max_depth_cone(rays, seen, edges, rigidity=RIGIDITY)
            out[f"{label} cost"] = costs["cost"]
            out[f"{label} e3d"] = _anchor_e3d(rays, seen, sol.depths, truth)
            left = [name for name in start["starts"] if f"{name} cost" not in out]
            if not left:
                break
            label = start["label"] = left[0]
    finally:
        cone_program._consistency_rounds = original
    return out


def _anchor_e3d(rays, seen, depths, truth) -> float:
    """Mean per-image e3D (F, A) over the entries the program placed."""
    placed = seen & np.isfinite(depths)  # the program leaves unbounded entries NaN
    return visible_e3d(np.nan_to_num(_scaled_shapes(rays, placed, depths)[1]), truth, placed)


def length_scores(rays, seen, edges, truth) -> dict[str, float]:
    """The lengths' part in the anchors' error: the joint program with each length scale
    (anchors' e3D; each length over the truth's, the truth's median over the images scaled to
    the same mean, as the mean ratio of the edges seen whole in fewer than 10 images and in
    20 or more), and every third image solved alone with the truth's lengths (an oracle) and
    with the program's."""
    both = seen[:, edges[:, 0]] & seen[:, edges[:, 1]]
    counts = both.sum(axis=0)
    true_lengths = np.median(
        np.linalg.norm(truth[:, edges[:, 0]] - truth[:, edges[:, 1]], axis=2), axis=0
    )
    row: dict[str, float] = {}
    for scale in ("edges", "pairs"):
        joint = cone_program.solve_max_depth_cone(
            rays, seen, edges, rigidity=RIGIDITY, length_scale=scale
        )
        used = np.isfinite(joint.lengths)
        ratio = joint.lengths / (
            true_lengths * np.mean(joint.lengths[used]) / np.mean(true_lengths[used])
        )
        row[f"{scale}: e3D"] = _anchor_e3d(rays, seen, joint.depths, truth)
        row[f"{scale}: length ratio, < 10 images"] = float(np.mean(ratio[used & (counts < 10)]))
        row[f"{scale}: length ratio, >= 20 images"] = float(np.mean(ratio[used & (counts >= 20)]))
        row[f"{scale}: isometry residual"] = cone_program.isometry_residual(
            rays, edges, joint.depths, joint.lengths
        )
        if scale == "edges":
            oracle = true_lengths * np.mean(joint.lengths[used]) / np.mean(true_lengths[used])
            for name, lengths in (("program's", joint.lengths), ("truth's", oracle)):
                alone = [
                    _anchor_e3d(rays[f : f + 1], seen[f : f + 1], cone_program.solve_max_depth_cone(
                        rays[f : f + 1], seen[f : f + 1], edges[used], rigidity=RIGIDITY,
                        lengths=lengths[used]).depths, truth[f : f + 1])
                    for f in range(0, len(rays), 3)
                ]  # fmt: skip
                row[f"images alone, {name} lengths: e3D"] = float(np.mean(alone))
    row["edges seen in < 10 images"] = float(np.mean(counts[counts > 0] < 10))
    return row


def scene_rays(
    kind: str, seed: int, args: argparse.Namespace
) -> Iterator[tuple[str, np.ndarray, np.ndarray, np.ndarray, float]]:
    """One scene rendered and tracked as in ``benchmarks/footage.py``: for the tracks, then
    perfect tracks of the same points, the label, the rays (F, P, 2; NaN where not seen), the
    visibility (F, P), the points' true paths (F, P, 3) and the focal length in pixels."""
    _, video = scene_video(kind, seed, args)
    tracks = replace(track_frames(list(video.frames), mask=video.mask), intrinsics=video.intrinsics)
    kept, perfect, index = perfect_tracks(video, tracks)
    truth = video.paths_3d[:, index]
    for label, source in (("tracks", kept), ("perfect", perfect)):
        n_frames, n_points = source.visibility.shape
        rays = video.intrinsics.normalise(source.W).reshape(n_frames, 2, n_points)
        rays = np.where(source.visibility[:, :, None], rays.transpose(0, 2, 1), np.nan)
        yield label, rays, source.visibility, truth, float(video.intrinsics.K[0, 0])


def run_scene(kind: str, seed: int, args: argparse.Namespace) -> list[dict[str, Any]]:
    """Rows (tracks, perfect) of one scene."""
    rows = []
    for label, rays, seen, truth, _ in scene_rays(kind, seed, args):
        n_points = seen.shape[1]
        anchors = spread_anchors(rays, seen, n_anchor=N_ANCHOR, seed=0)
        r, s = rays[:, anchors], seen[:, anchors]
        edges = neighbour_edges(r, s, k=K)
        row: dict[str, Any] = {"kind": kind, "seed": seed, "source": label, "points": n_points}
        if args.oracle_start or args.smoothed_start:
            starts = oracle_starts if args.oracle_start else smoothed_starts
            row.update(rounds_from_starts(r, s, edges, truth[:, anchors], starts))
        elif args.lengths:
            row.update(length_scores(r, s, edges, truth[:, anchors]))
        else:
            cone = solve_by_key_images(r, s, edges, rigidity=RIGIDITY, outlier_price=np.inf)
            depths = hold_cut_off_groups(r, s, edges, cone.depths, cone.lengths, cone.shrink)
            row["anchors"] = _anchor_e3d(r, s, depths, truth[:, anchors])
            for name, dense in dense_variants(rays, seen, anchors, depths).items():
                shapes = _scaled_shapes(rays, seen, dense)[1]
                row[name] = visible_e3d(np.nan_to_num(shapes), truth, seen)
        print(row, flush=True)
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2, 10, 11, 12])
    parser.add_argument("--held-out", type=int, nargs="*", default=[20, 21, 22, 30, 31, 32])
    parser.add_argument("--oracle-start", action="store_true")
    parser.add_argument("--smoothed-start", action="store_true")
    parser.add_argument("--lengths", action="store_true", help="the lengths' part in the error")
    parser.add_argument("--tag", default="")
    args = parser.parse_args()
    args.frames, args.width, args.height, args.mesh = 30, 640, 480, 6000
    meta = provenance()
    splits: dict[str, list[dict[str, Any]]] = {}
    for split, seeds in (("design", args.seeds), ("held-out", args.held_out)):
        for seed in seeds:
            splits.setdefault(split, []).extend(
                run_scene(FOOTAGE_KINDS[seed % len(FOOTAGE_KINDS)], seed, args)
            )
            write(f"dense_stage{args.tag}", meta, splits)


def write(name: str, meta: dict[str, Any], splits: dict[str, list[dict[str, Any]]]) -> None:
    """JSON and one markdown table per split (columns: every score of the rows)."""
    write_json(OUT / f"{name}.json", meta, splits=splits)
    body: list[str] = []
    for split, rows in splits.items():
        scores = [k for k in rows[0] if k not in ("kind", "seed", "source", "points")]
        lines = [
            [r["kind"], r["seed"], r["source"], r["points"]]
            + [f"{r[k]:.4f}" if isinstance(r[k], float) else r[k] for k in scores]
            for r in rows
        ]
        header = ["kind", "seed", "tracks", "points", *scores]
        body += [f"## {split}", "", *table(header, lines), ""]
    write_markdown(OUT / f"{name}.md", "The surface prior's dense stage", meta, body)


if __name__ == "__main__":
    main()
