"""Video to 3D on rendered perspective footage: tracks against perfect tracks, per kind.

Every scene is a sheet bending isometrically in front of a static pinhole camera
(``moju_core.datasets.footage_scenes.footage_scene``: curl, crease or cloth; 0.2-0.3 m,
2-5 of its lengths away, turning 5-30 degrees, its depth changing by 8-20 %), rendered at
640 x 480 with f = 1.2 x 640 px (``moju_core.footage.perspective_render``), tracked with
``track_frames`` (the true first-frame mask, the default step) and reconstructed with
``reconstruct(W, SolverParams(seed=0), visibility=..., intrinsics=camera)`` (defaults):

* ``tracks``: the solvable tracks on the surface, as tracked;
* ``perfect``: the true image paths of the same points, with the tracker's visibility
  (``benchmarks/tracking.py:perfect_tracks``);
* ``ortho tracks`` / ``ortho perfect``: the same without the camera (the orthographic
  solve), an ablation.

Scores against the true 3D paths of the same points (metres, camera frame):
``scaled_e3d`` (per-frame scale + Procrustes, every entry, hidden ones included, as the
solver returns every point in every frame), the same over the visible entries only, and the
out-of-plane ratio. The rigid baseline is the better of two single rigid shapes aligned to
every frame with a per-frame scale: the first frame's true shape, and the generalised
Procrustes mean of all true frames. Targets: ``e3D tracks <= 1.15 e3D perfect + 0.005``,
out-of-plane ratio (tracks) >= 0.8, ``e3D tracks <= 0.5 rigid``.

By default each seed renders one kind, ``FOOTAGE_KINDS[seed % 3]`` (design seeds 0-2 and
held-out seeds 10-12 each cover the three kinds once); ``--all-kinds`` renders every kind for
every seed. Results: ``benchmarks/results/footage/footage[_quick].json`` and ``.md``::

    PYTHONPATH=. nice python benchmarks/footage.py              # seeds 0-2 design, 10-12 held out
    PYTHONPATH=. nice python benchmarks/footage.py --quick      # one small scene
    PYTHONPATH=. nice python benchmarks/footage.py --tracks-only  # pixel errors by slant, no solve
    PYTHONPATH=. nice python benchmarks/footage.py --seeds 2 1 --held-out --drop-px 2 \\
        --no-ortho --tag _drop2px  # oracle: without the tracks that err by > 2 px
    PYTHONPATH=. nice python benchmarks/footage.py --no-ortho --smoothed-starts \\
        --tag _smoothed_starts  # ablation: the prior's smoothed starts, side by side
    PYTHONPATH=. nice python benchmarks/footage.py --no-ortho --pair-lengths \\
        --tag _pair_lengths  # ablation: lengths scaled over the (image, edge) pairs
    PYTHONPATH=. nice python benchmarks/footage.py --no-ortho --edge-lengths \\
        --tag _edge_lengths  # ablation: lengths scaled over the edges alone
    PYTHONPATH=. nice python benchmarks/footage.py --no-ortho --unchecked \\
        --tag _unchecked  # ablation: the solve without its neighbour check
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import time
import warnings
from dataclasses import replace
from typing import Any
from unittest import mock

import numpy as np
from harness import RESULTS, provenance, table, write_json, write_markdown
from tracking import perfect_tracks

from moju_core import SolverParams, neighbour_check, perspective, reconstruct
from moju_core.cameras.intrinsics import DEFAULT_FOCAL_FACTOR, Intrinsics
from moju_core.datasets.footage_scenes import FOOTAGE_KINDS, FootageScene, footage_scene
from moju_core.datasets.totem import out_of_plane_ratio, scaled_e3d
from moju_core.footage.perspective_render import PerspectiveVideo, render_perspective
from moju_core.footage.render import score_tracks
from moju_core.footage.tracking import Tracks, track_frames
from moju_core.metrics import align, center_frames

OUT = RESULTS / "footage"
#: The surface prior's options measured side by side with its defaults: command-line flag ->
#: (row prefix, ``max_depth_shapes`` options, title of the table).
PRIOR_ABLATIONS: dict[str, tuple[str, dict[str, Any], str]] = {
    "smoothed_starts": (
        "starts",
        {"smoothed_starts": True},
        "The prior's smoothed starts (ablation)",
    ),
    "pair_lengths": (
        "pairs",
        {"length_scale": "pairs"},
        "Lengths scaled over the (image, edge) pairs (ablation)",
    ),
    "edge_lengths": (
        "edges",
        {"length_scale": "edges"},
        "Lengths scaled over the edges alone, the program of MDH (ablation)",
    ),
}
#: Tolerances of the targets: tracked <= RATIO x perfect + SLACK; out-of-plane >= OOP;
#: tracked <= RIGID_FRACTION x rigid.
RATIO, SLACK, OOP, RIGID_FRACTION = 1.15, 0.005, 0.8, 0.5
#: Pixels within this distance of the first frame's silhouette count as "near the edge".
EDGE_PX = 4.0
#: Bins of |cos(angle between the viewing ray and the surface normal)| of slant_errors.
SLANT_BINS = ((0.0, 0.2), (0.2, 0.4), (0.4, 0.7), (0.7, 1.01))


def scene_video(
    kind: str, seed: int, args: argparse.Namespace, focal_factor: float = DEFAULT_FOCAL_FACTOR
) -> tuple[FootageScene, PerspectiveVideo]:
    """Render one scene at the run's size; the focal length is ``focal_factor`` x the larger
    side (by default the default camera's, 1.2)."""
    scene = footage_scene(kind, n_frames=args.frames, n_points=args.mesh, seed=seed)
    camera = Intrinsics.from_focal(
        focal_factor * max(args.width, args.height), (args.width, args.height)
    )
    return scene, render_perspective(
        scene.shapes,
        scene.faces,
        scene.uv,
        camera,
        width=args.width,
        height=args.height,
        seed=seed,
        name=f"{kind} {seed}",
    )


def procrustes_mean(shapes: np.ndarray) -> np.ndarray:
    """The generalised Procrustes mean (P, 3) of ``shapes`` (F, P, 3): frames centred, scaled
    and rotated onto the running mean, 10 rounds (the first frame starts it)."""
    centred = center_frames(shapes)
    mean = centred[0]
    for _ in range(10):
        target = np.broadcast_to(mean, centred.shape)
        norms = np.linalg.norm(centred.reshape(len(centred), -1), axis=1)
        scaled = centred * (np.linalg.norm(mean) / norms)[:, None, None]
        mean = align(scaled, target, "procrustes").mean(axis=0)
    return mean


def rigid_baselines(truth: np.ndarray) -> dict[str, float]:
    """e3D of single rigid shapes scaled and aligned to every frame of ``truth`` (F, P, 3).

    ``first``: the first true frame; ``mean``: :func:`procrustes_mean`.
    """
    n_frames = truth.shape[0]
    mean = procrustes_mean(truth)
    return {
        "first": scaled_e3d(np.repeat(truth[:1], n_frames, axis=0), truth),
        "mean": scaled_e3d(np.repeat(mean[None], n_frames, axis=0), truth),
    }


def visible_e3d(estimate: np.ndarray, truth: np.ndarray, visible: np.ndarray) -> float:
    """``scaled_e3d`` frame by frame over the visible points (F, P) only, averaged."""
    return float(
        np.mean(
            [scaled_e3d(estimate[f, v][None], truth[f, v][None]) for f, v in enumerate(visible)]
        )
    )


def neighbour_check_off() -> contextlib.AbstractContextManager:
    """Within the block, the perspective solve keeps every seen position (the ablation of
    ``moju_core.neighbour_check``)."""
    return mock.patch.object(neighbour_check, "trusted", lambda W, visibility: visibility)


def prior_options(**options: Any) -> contextlib.AbstractContextManager:
    """Within the block, the perspective prior runs ``max_depth_shapes`` with ``options``
    (its keyword arguments, for an ablation of a setting the solver does not expose)."""
    original = perspective.max_depth_shapes
    return mock.patch.object(
        perspective, "max_depth_shapes", functools.partial(original, **options)
    )


def solve(
    source: Tracks, camera: Intrinsics | None, truth: np.ndarray, **prior: Any
) -> dict[str, Any]:
    """Reconstruct ``source`` with default parameters (seed 0), the surface prior's options
    ``prior`` (none: its defaults), and score it."""
    start = time.perf_counter()
    with warnings.catch_warnings(), prior_options(**prior):
        warnings.simplefilter("ignore")
        result = reconstruct(
            source.W, SolverParams(seed=0), visibility=source.visibility, intrinsics=camera
        )
    return {
        "e3d": scaled_e3d(result.shapes, truth),
        "e3d_visible": visible_e3d(result.shapes, truth, source.visibility),
        "out_of_plane": out_of_plane_ratio(result.shapes, truth),
        "seconds": time.perf_counter() - start,
        "set_aside": int(source.visibility.sum() - result.visibility.sum()),
    }


def track_diagnostics(video: PerspectiveVideo, kept: Tracks, index: np.ndarray) -> dict:
    """Pixel errors of the solved tracks against their true paths, overall and by region.

    ``edge``: tracks starting within EDGE_PX of the first frame's silhouette; ``drift``: the
    median error in the last quarter of the frames over that in the first quarter.
    """
    from scipy.ndimage import distance_transform_edt

    n_frames = kept.n_frames
    positions = kept.W.reshape(n_frames, 2, -1).transpose(0, 2, 1)
    error = np.linalg.norm(positions - video.paths_2d[:, index], axis=2)  # NaN where lost
    distance = distance_transform_edt(video.mask)
    start = video.points_xy[index]
    near_edge = distance[start[:, 1], start[:, 0]] <= EDGE_PX
    quarter = max(1, n_frames // 4)
    early, late = np.nanmedian(error[1 : quarter + 1]), np.nanmedian(error[-quarter:])
    return {
        "median_px": float(np.nanmedian(error[1:])),
        "p90_px": float(np.nanpercentile(error[1:], 90)),
        "rms_px": float(np.sqrt(np.nanmean(error[1:] ** 2))),
        "edge_fraction": float(near_edge.mean()),
        "edge_median_px": float(np.nanmedian(error[1:, near_edge])) if near_edge.any() else None,
        "interior_median_px": float(np.nanmedian(error[1:, ~near_edge])),
        "drift": float(late / early) if early > 0 else None,
        "late_median_px": float(late),
        "kept_hidden": float(
            (kept.visibility & ~video.visible[:, index]).sum() / max(kept.visibility.sum(), 1)
        ),
    }


def slant_errors(
    scene: FootageScene, video: PerspectiveVideo, kept: Tracks, index: np.ndarray
) -> dict[str, Any]:
    """The tracks' pixel errors by how obliquely the surface is seen.

    ``|cos|`` of the angle between the viewing ray and the surface normal at the point (the
    area-weighted normal of the nearest mesh vertex), in bins SLANT_BINS; per bin the share
    of the kept track-frames after the first, their median and 90th percentile error (px).
    Also the tracks whose error exceeds 2 px in some frame and the rms error without the
    worst 1 % of the track-frames.
    """
    from scipy.spatial import cKDTree

    corners = scene.shapes[:, scene.faces]  # (F, M, 3, 3)
    normals = np.cross(corners[:, :, 1] - corners[:, :, 0], corners[:, :, 2] - corners[:, :, 0])
    vertex_normals = np.zeros_like(scene.shapes)
    for k in range(3):
        np.add.at(vertex_normals, (slice(None), scene.faces[:, k]), normals)
    nearest = cKDTree(scene.shapes[0]).query(video.paths_3d[0, index])[1]
    normal = vertex_normals[:, nearest]
    points = video.paths_3d[:, index]
    cosine = np.abs(np.einsum("fpk,fpk->fp", normal, points)) / (
        np.linalg.norm(normal, axis=2) * np.linalg.norm(points, axis=2)
    )
    n_frames = kept.n_frames
    error = np.linalg.norm(
        kept.W.reshape(n_frames, 2, -1).transpose(0, 2, 1) - video.paths_2d[:, index], axis=2
    )
    valid = np.isfinite(error)
    valid[0] = False
    bins = []
    for low, high in SLANT_BINS:
        chosen = valid & (cosine >= low) & (cosine < high)
        values = error[chosen]
        bins.append({
            "cos": [low, high], "share": float(chosen.sum() / valid.sum()),
            "median_px": float(np.median(values)) if values.size else None,
            "p90_px": float(np.percentile(values, 90)) if values.size else None,
        })  # fmt: skip
    errors = np.sort(error[valid])
    worst = np.nanmax(np.where(valid, error, np.nan), axis=0)
    return {
        "bins": bins,
        "tracks_over_2px": int(np.sum(worst > 2.0)),
        "rms_px": float(np.sqrt(np.mean(errors**2))),
        "rms_px_without_worst_1pc": float(np.sqrt(np.mean(errors[: int(0.99 * errors.size)] ** 2))),
    }


def drop_wrong_tracks(
    video: PerspectiveVideo, kept: Tracks, perfect: Tracks, index: np.ndarray, limit_px: float
) -> tuple[Tracks, Tracks, np.ndarray]:
    """An oracle ablation: leave out the tracks whose error exceeds ``limit_px`` in some frame
    (judged against the ground truth), from the tracks and from the perfect tracks alike."""
    n_frames = kept.n_frames
    positions = kept.W.reshape(n_frames, 2, -1).transpose(0, 2, 1)
    error = np.linalg.norm(positions - video.paths_2d[:, index], axis=2)
    good = ~(np.nan_to_num(error, nan=0.0) > limit_px).any(axis=0)

    def subset(tracks: Tracks) -> Tracks:
        return replace(
            tracks, W=tracks.W[:, good], visibility=tracks.visibility[:, good],
            colors=tracks.colors[good],
        )  # fmt: skip

    return subset(kept), subset(perfect), index[good]


def run_scene(kind: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    """Render, track and reconstruct one scene; the row of the tables."""
    start = time.perf_counter()
    scene, video = scene_video(kind, seed, args)
    rendered = time.perf_counter()
    camera = video.intrinsics
    tracks = replace(track_frames(list(video.frames), mask=video.mask), intrinsics=camera)
    tracked = time.perf_counter()
    kept, perfect, index = perfect_tracks(video, tracks)
    if args.drop_px is not None:
        kept, perfect, index = drop_wrong_tracks(video, kept, perfect, index, args.drop_px)
    truth = video.paths_3d[:, index]
    scores = score_tracks(video, tracks.W)
    row: dict[str, Any] = {
        "kind": kind,
        "seed": seed,
        "frames": video.n_frames,
        "points": int(index.size),
        "kept": float(kept.visibility.mean()),
        "median_error_px": scores.median_error,
        "p90_error_px": scores.p90_error,
        "track_px": track_diagnostics(video, kept, index),
        "rigid": rigid_baselines(truth),
        "render_s": rendered - start,
        "track_s": tracked - rendered,
    }
    row["track_px"]["slant"] = slant_errors(scene, video, kept, index)
    if args.tracks_only:
        return row
    solves = {"tracks": (kept, camera), "perfect": (perfect, camera)}
    if not args.no_ortho:
        solves.update({"ortho tracks": (kept, None), "ortho perfect": (perfect, None)})
    for label, (source, intrinsics) in solves.items():
        row[label] = solve(source, intrinsics, truth)
    for flag, (prefix, options, _) in PRIOR_ABLATIONS.items():
        if getattr(args, flag):  # side by side with the default solves, for the time ratio
            for label in ("tracks", "perfect"):
                source, intrinsics = solves[label]
                row[f"{prefix} {label}"] = solve(source, intrinsics, truth, **options)
    if args.unchecked:
        for label in ("tracks", "perfect"):
            source, intrinsics = solves[label]
            with neighbour_check_off():
                row[f"unchecked {label}"] = solve(source, intrinsics, truth)
    return judge(row)


def judge(row: dict[str, Any]) -> dict[str, Any]:
    """Add the rigid baseline's choice and the three targets to a scene's row."""
    rigid_kind = min(row["rigid"], key=row["rigid"].get)
    rigid = row["rigid"][rigid_kind]
    tracked, perfect = row["tracks"]["e3d"], row["perfect"]["e3d"]
    row["rigid_best"] = {"shape": rigid_kind, "e3d": rigid}
    row["targets"] = {
        "tracks_vs_perfect": tracked <= RATIO * perfect + SLACK,
        "out_of_plane": row["tracks"]["out_of_plane"] >= OOP,
        "vs_rigid": tracked <= RIGID_FRACTION * rigid,
    }
    return row


def scenes(seeds: list[int], all_kinds: bool) -> list[tuple[str, int]]:
    """(kind, seed) pairs: every kind per seed, or the seed's own kind."""
    if all_kinds:
        return [(kind, seed) for seed in seeds for kind in FOOTAGE_KINDS]
    return [(FOOTAGE_KINDS[seed % len(FOOTAGE_KINDS)], seed) for seed in seeds]


def summary(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Means of a split's rows."""

    def mean(get) -> float:
        return float(np.mean([get(r) for r in rows]))

    out = {
        f"e3d {label}": mean(lambda r, x=label: r[x]["e3d"])
        for label in ("tracks", "perfect", "ortho tracks", "ortho perfect")
        if label in rows[0]
    }
    out["out_of_plane tracks"] = mean(lambda r: r["tracks"]["out_of_plane"])
    out["e3d rigid"] = mean(lambda r: r["rigid_best"]["e3d"])
    for target in ("tracks_vs_perfect", "out_of_plane", "vs_rigid"):
        out[f"met {target}"] = int(sum(r["targets"][target] for r in rows))
    out["scenes"] = len(rows)
    return out


def _fmt(value: float | None, digits: int = 4) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def markdown(splits: dict[str, list[dict[str, Any]]]) -> list[str]:
    """The tables: one row per scene, per split; then the tracks' diagnostics."""
    header = [
        "split",
        "kind",
        "seed",
        "points",
        "kept",
        "e3D tracks",
        "e3D perfect",
        "ratio",
        "<= 1.15 p + 0.005",
        "oop tracks",
        "oop perfect",
        "rigid (shape)",
        "<= 0.5 rigid",
        "e3D ortho tracks",
        "e3D ortho perfect",
        "solve s (t, p)",
    ]
    lines, diag = [], []
    for split, rows in splits.items():
        for r in rows:
            t, p = r["tracks"], r["perfect"]
            ortho = [_fmt(r.get(k, {}).get("e3d")) for k in ("ortho tracks", "ortho perfect")]
            lines.append(
                [
                    split,
                    r["kind"],
                    r["seed"],
                    r["points"],
                    f"{r['kept']:.0%}",
                    _fmt(t["e3d"]),
                    _fmt(p["e3d"]),
                    f"{t['e3d'] / p['e3d']:.2f}",
                    "yes" if r["targets"]["tracks_vs_perfect"] else "no",
                    _fmt(t["out_of_plane"], 2),
                    _fmt(p["out_of_plane"], 2),
                    f"{r['rigid_best']['e3d']:.4f} ({r['rigid_best']['shape']})",
                    "yes" if r["targets"]["vs_rigid"] else "no",
                    *ortho,
                    f"{t['seconds']:.0f}, {p['seconds']:.0f}",
                ]
            )
            px = r["track_px"]
            diag.append(
                [
                    split,
                    r["kind"],
                    r["seed"],
                    _fmt(t["e3d_visible"]),
                    _fmt(p["e3d_visible"]),
                    _fmt(px["median_px"], 3),
                    _fmt(px["p90_px"], 2),
                    _fmt(px["rms_px"], 2),
                    f"{px['edge_fraction']:.0%}",
                    _fmt(px["edge_median_px"], 3),
                    _fmt(px["interior_median_px"], 3),
                    _fmt(px["late_median_px"], 3),
                    _fmt(px["drift"], 2),
                    f"{px['kept_hidden']:.2%}",
                ]
            )
    body = table(header, lines)
    body += ["", "## Visible-entry e3D and the tracks' pixel errors", ""]
    body += table(
        [
            "split",
            "kind",
            "seed",
            "e3D vis tracks",
            "e3D vis perfect",
            "median px",
            "p90 px",
            "rms px",
            "edge tracks",
            "edge median px",
            "interior median px",
            "last-quarter median px",
            "drift (last / first quarter)",
            "kept hidden",
        ],
        diag,
    )
    ablations = [(prefix, title) for prefix, _, title in PRIOR_ABLATIONS.values()]
    ablations.append(("unchecked", "Without the neighbour check (ablation)"))
    for prefix, title in ablations:
        if any(f"{prefix} tracks" in r for rows in splits.values() for r in rows):
            body += ["", *prior_ablation_table(splits, prefix, title)]
    body += ["", "## Means per split", ""]
    for split, rows in splits.items():
        body.append(
            f"* {split}: "
            + ", ".join(
                f"{k} {v:.4f}" if isinstance(v, float) else f"{k} {v}"
                for k, v in summary(rows).items()
            )
        )
    return body


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="one small scene, to prove it runs")
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--held-out", type=int, nargs="*", default=[10, 11, 12])
    parser.add_argument("--all-kinds", action="store_true", help="every kind for every seed")
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--mesh", type=int, default=6000, help="vertices of the sheet's mesh")
    parser.add_argument("--no-ortho", action="store_true", help="skip the orthographic solves")
    parser.add_argument("--tag", default="", help="suffix of the result files")
    for flag, (_, options, title) in PRIOR_ABLATIONS.items():
        parser.add_argument(
            "--" + flag.replace("_", "-"),
            action="store_true",
            help=f"{title}: also solve with max_depth_shapes options {options}",
        )
    parser.add_argument(
        "--tracks-only", action="store_true", help="render and track only: the pixel errors"
    )
    parser.add_argument(
        "--unchecked",
        action="store_true",
        help="ablation: also solve without the neighbour check (every seen position kept)",
    )
    parser.add_argument(
        "--drop-px",
        type=float,
        default=None,
        help="oracle ablation: leave out tracks whose true error exceeds this in some frame",
    )
    args = parser.parse_args()
    if args.quick:
        args.seeds, args.held_out, args.frames = [0], [], 10
        args.width, args.height, args.mesh = 320, 240, 2000
    meta = provenance()
    name = "footage" + ("_tracks" if args.tracks_only else "")
    name += ("_quick" if args.quick else "") + args.tag
    settings = {k: getattr(args, k) for k in ("frames", "width", "height", "mesh", "all_kinds")}
    splits: dict[str, list[dict[str, Any]]] = {}
    for split, seeds in (("design", args.seeds), ("held-out", args.held_out)):
        for kind, seed in scenes(seeds, args.all_kinds):
            row = run_scene(kind, seed, args)
            if args.tracks_only:
                splits.setdefault(split, []).append(row)
                write_tracks_only(name, meta, settings, splits)
                continue
            print(
                split,
                {k: row[k] for k in ("kind", "seed", "targets")},
                {k: round(row[k]["e3d"], 4) for k in ("tracks", "perfect")},
                flush=True,
            )
            splits.setdefault(split, []).append(row)
            write_results(name, meta, settings, splits)  # after every scene: long runs


def prior_ablation_table(
    splits: dict[str, list[dict[str, Any]]], prefix: str, title: str
) -> list[str]:
    """An ablation of :data:`PRIOR_ABLATIONS` (rows ``"{prefix} tracks"`` and ``"{prefix}
    perfect"``) against the default solves: every entry and the visible ones, the out-of-plane
    ratio and the time ratio of each pair."""
    header = ["split", "kind", "seed", "tracks"]
    header += ["e3D default", f"e3D {prefix}", "e3D vis default", f"e3D vis {prefix}"]
    header += ["oop default", f"oop {prefix}", "time ratio"]
    lines = []
    for split, rows in splits.items():
        for r in rows:
            for label in ("tracks", "perfect"):
                a, b = r[label], r[f"{prefix} {label}"]
                lines.append([
                    split, r["kind"], r["seed"], label, _fmt(a["e3d"]), _fmt(b["e3d"]),
                    _fmt(a["e3d_visible"]), _fmt(b["e3d_visible"]),
                    _fmt(a["out_of_plane"], 2), _fmt(b["out_of_plane"], 2),
                    _fmt(b["seconds"] / a["seconds"], 2),
                ])  # fmt: skip
    return [f"## {title}", "", *table(header, lines)]


def write_tracks_only(
    name: str, meta: dict[str, Any], settings: dict[str, Any], splits: dict[str, list[dict]]
) -> None:
    """``--tracks-only``: the tracks' errors by slant, JSON and markdown."""
    write_json(OUT / f"{name}.json", meta, settings=settings, splits=splits)
    header = ["split", "kind", "seed", "tracks", "median px"]
    header += [f"|cos| {lo}-{min(hi, 1.0)}: share, median, p90 px" for lo, hi in SLANT_BINS]
    header += ["tracks > 2 px", "rms px", "rms px without worst 1 %"]
    lines = []
    for split, rows in splits.items():
        for r in rows:
            slant = r["track_px"]["slant"]
            cells = [
                f"{b['share']:.1%}, {_fmt(b['median_px'], 2)}, {_fmt(b['p90_px'], 2)}"
                for b in slant["bins"]
            ]
            lines.append([
                split, r["kind"], r["seed"], r["points"], _fmt(r["track_px"]["median_px"], 3),
                *cells, slant["tracks_over_2px"], _fmt(slant["rms_px"], 2),
                _fmt(slant["rms_px_without_worst_1pc"], 2),
            ])  # fmt: skip
    body = table(header, lines)
    write_markdown(OUT / f"{name}.md", "Tracking errors on perspective footage", meta, body)
    print("\n".join(body), flush=True)


def write_results(
    name: str, meta: dict[str, Any], settings: dict[str, Any], splits: dict[str, list[dict]]
) -> None:
    """Write the JSON and the markdown tables of the scenes so far (and print the tables)."""
    write_json(
        OUT / f"{name}.json",
        meta,
        settings=settings,
        splits=splits,
        summary={s: summary(rows) for s, rows in splits.items()},
    )
    body = markdown(splits)
    write_markdown(OUT / f"{name}.md", "Video to 3D on perspective footage", meta, body)
    print("\n".join(body), flush=True)


if __name__ == "__main__":
    main()
