"""What an unknown focal length costs the perspective solve, and what estimating it recovers.

The same tracks are solved (``reconstruct``, defaults, seed 0) with three cameras:

* ``true``: the camera that made them (given);
* ``default``: COLMAP's default focal length, 1.2 x the larger image side, used as given
  (what a user without K got before the estimate; ``Intrinsics.from_focal``, no estimate);
* ``estimated``: the default camera of the frame size (``Intrinsics.default_for``), whose
  focal length the solve estimates (``moju_core.priors.focal_length``).

Inputs: the four real ToTem sequences (their pixel tracks; frame size 2 c + 1 from their
principal point c); the bent sheets of ``benchmarks/perspective.py`` (``bent_sheet``, 0.5 px
of noise at f = 800 px) placed in a 1280 x 720 frame (default 1536 px, 1.9 x too long); and
rendered footage (``benchmarks/footage.py``'s scenes, tracked by ``track_frames``) rendered
with a focal length of ``--factors`` x the larger side: 0.75 (a phone's main camera: the
default is 1.6 x too long) and 1.2 (the default is the truth: what the estimate costs where
nothing is wrong). e3D as ``scaled_e3d`` (every entry), with the focal length each solve used
over the true one, and the estimate's share of the solve's time (same run). Results in
``benchmarks/results/focal_length/``::

    PYTHONPATH=.:benchmarks python benchmarks/focal_length.py totem sheets --seeds 0 1 2 3
    PYTHONPATH=.:benchmarks python benchmarks/focal_length.py footage --scenes crease:10 \\
        cloth:11 curl:12 --factors 0.75 --tag _held_out
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import replace
from typing import Any

import numpy as np
from footage import rigid_baselines, scene_video
from harness import RESULTS, provenance, table, write_json, write_markdown
from surface_prior import bent_sheet
from tracking import perfect_tracks

from moju_core import SolverParams, reconstruct
from moju_core.cameras.intrinsics import DEFAULT_FOCAL_FACTOR, Intrinsics
from moju_core.datasets.totem import TOTEM_NAMES, load_totem, scaled_e3d
from moju_core.footage.tracking import track_frames

OUT = RESULTS / "focal_length"
SHEET_FOCAL = 800.0
SHEET_FRAME = (1280, 720)


def solve(W: np.ndarray, visibility: np.ndarray, camera: Intrinsics, truth: np.ndarray) -> dict:
    """e3D, the focal length used (pixels, from the plan) and the time of one solve."""
    masked = None if visibility.all() else visibility
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = reconstruct(W, SolverParams(seed=0), visibility=masked, intrinsics=camera)
    plan = result.diagnostics.plan
    return {
        "e3d": scaled_e3d(result.shapes, truth),
        "focal_px": plan.focal_px,
        "origin": plan.focal_origin,
        "seconds": time.perf_counter() - start,
        "estimate_s": result.timings.get("focal_length", 0.0),
    }


def three_ways(
    W: np.ndarray, visibility: np.ndarray, true: Intrinsics, frame: tuple[int, int], truth
) -> dict[str, Any]:
    """The solves with the true, the default (as given) and the estimated camera."""
    default = Intrinsics.default_for(frame)
    cameras = {"true": true, "estimated": default}
    if not np.isclose(default.fx, true.fx):  # else the default solve is the true one
        cameras["default"] = true.with_focal(default.fx, "focal")
    row = {name: solve(W, visibility, camera, truth) for name, camera in cameras.items()}
    row["default"] = row.get("default", row["true"])
    row["true_focal_px"] = true.fx
    return row


def totem_rows(directory: str) -> dict[str, Any]:
    rows = {}
    for name in TOTEM_NAMES:
        seq = load_totem(directory, name)
        n_frames, n_points, _ = seq.pixels.shape
        W = seq.pixels.transpose(0, 2, 1).reshape(2 * n_frames, n_points)
        true = Intrinsics(np.asarray(seq.K, float), "given")
        frame = tuple(int(round(2 * c + 1)) for c in true.principal_point)
        rows[name] = three_ways(W, seq.visibility, true, frame, seq.truth)
    return rows


def sheet_rows(seeds: list[int]) -> dict[str, Any]:
    rows = {}
    true = Intrinsics.from_focal(SHEET_FOCAL, SHEET_FRAME)
    for seed in seeds:
        rays, truth = bent_sheet(noise_px=0.5, focal_px=SHEET_FOCAL, seed=seed)
        W = true.to_pixels(rays.transpose(0, 2, 1).reshape(-1, rays.shape[1]))
        seen = np.ones(rays.shape[:2], bool)
        rows[f"sheet {seed}"] = three_ways(W, seen, true, SHEET_FRAME, truth)
    return rows


def footage_rows(scenes: list[str], factors: list[float]) -> dict[str, Any]:
    rows = {}
    for scene in scenes:
        kind, seed = scene.split(":")
        for factor in factors:
            args = argparse.Namespace(frames=30, width=640, height=480, mesh=6000)
            _, video = scene_video(kind, int(seed), args, factor)
            camera = video.intrinsics
            tracks = replace(track_frames(list(video.frames), mask=video.mask), intrinsics=camera)
            kept, _, index = perfect_tracks(video, tracks)
            truth = video.paths_3d[:, index]
            row = three_ways(kept.W, kept.visibility, camera, (640, 480), truth)
            row["rigid"] = min(rigid_baselines(truth).values())
            rows[f"{kind} {seed}, f = {factor} x side"] = row
    return rows


def markdown(rows: dict[str, Any]) -> list[str]:
    body = []
    for name, row in rows.items():
        true = row["true_focal_px"]
        body.append(
            [
                name,
                f"{true:.0f}",
                f"{row['true']['e3d']:.4f}",
                f"{row['default']['e3d']:.4f} ({row['default']['focal_px'] / true:.2f})",
                f"{row['estimated']['e3d']:.4f} ({row['estimated']['focal_px'] / true:.2f}, "
                f"{row['estimated']['origin']})",
                f"{row['estimated']['estimate_s']:.0f} / {row['estimated']['seconds']:.0f}",
            ]
        )
    header = ["input", "true focal px", "e3D true K", "e3D default (focal / true)",
              "e3D estimated (focal / true, origin)", "estimate s / solve s"]  # fmt: skip
    return table(header, body)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("parts", nargs="+", choices=["totem", "sheets", "footage"])
    parser.add_argument("--totem", default="../shared/data/totem")
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2, 3])
    parser.add_argument("--scenes", nargs="*", default=["crease:10", "cloth:11", "curl:12"])
    parser.add_argument("--factors", type=float, nargs="*", default=[0.75, DEFAULT_FOCAL_FACTOR])
    parser.add_argument("--tag", default="")
    args = parser.parse_args()
    meta = provenance()
    rows: dict[str, Any] = {}
    if "totem" in args.parts:
        rows.update(totem_rows(args.totem))
    if "sheets" in args.parts:
        rows.update(sheet_rows(args.seeds))
    if "footage" in args.parts:
        rows.update(footage_rows(args.scenes, args.factors))
    lines = markdown(rows)
    print("\n".join(lines))
    write_json(OUT / f"focal_length{args.tag}.json", meta, rows=rows)
    write_markdown(OUT / f"focal_length{args.tag}.md", "Focal length: true, default, estimated",
                   meta, lines)  # fmt: skip


if __name__ == "__main__":
    main()
