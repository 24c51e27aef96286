"""The maximum-depth prior on long sequences: all images jointly against key images.

:func:`moju_core.priors.key_images.solve_by_key_images` solves the cone program jointly on at
most ``MAX_KEY_IMAGES`` images and every other image alone with their edge lengths fixed. This
script renders footage scenes longer than that (``benchmarks/footage.py``'s scenes, 640 x 480,
f = 1.2 x 640 px), takes perfect tracks of the tracker's points (so that only the prior's
solve differs), and runs :func:`moju_core.priors.max_depth.max_depth_shapes` three ways:

* ``joint``: every image in one program (the formulation; its cost grows faster than F);
* ``keys 30``: the default (``MAX_KEY_IMAGES = 30``);
* ``keys 10``: fewer key images, to see how much the lengths depend on their number.

Scores: the seen-entry e3D (per-frame scale and Procrustes) of the prior's shapes against the
true 3D points, and the cone program's wall time as a ratio to the joint solve's in the same
run. Results: ``benchmarks/results/surface_prior/key_images.json`` and ``.md``::

    PYTHONPATH=. nice python benchmarks/key_images.py                       # design scenes
    PYTHONPATH=. nice python benchmarks/key_images.py --scenes curl:12 cloth:11 --tag _held_out
"""

from __future__ import annotations

import argparse
import warnings
from dataclasses import replace
from typing import Any

import numpy as np
from footage import scene_video, visible_e3d
from harness import RESULTS, provenance, table, write_json, write_markdown
from tracking import perfect_tracks

from moju_core.footage.tracking import track_frames
from moju_core.priors.max_depth import max_depth_shapes

OUT = RESULTS / "surface_prior"
VARIANTS = {"joint": 10**9, "keys 30": 30, "keys 10": 10}


def scene_rays(kind: str, seed: int, args: argparse.Namespace) -> tuple[np.ndarray, ...]:
    """Rays (F, P, 2) of perfect tracks of the tracker's points, their visibility, the truth."""
    _, video = scene_video(kind, seed, args)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tracks = track_frames(list(video.frames), mask=video.mask)
    _, perfect, index = perfect_tracks(video, replace(tracks, intrinsics=video.intrinsics))
    n_frames = perfect.n_frames
    pixels = perfect.W.reshape(n_frames, 2, -1).transpose(0, 2, 1)
    rays = video.intrinsics.normalise(perfect.W).reshape(n_frames, 2, -1).transpose(0, 2, 1)
    rays = np.where(np.isfinite(pixels), rays, np.nan)
    return rays, perfect.visibility, video.paths_3d[:, index]


def run_scene(kind: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    """The three variants on one scene."""
    rays, seen, truth = scene_rays(kind, seed, args)
    row: dict[str, Any] = {"kind": kind, "seed": seed, "frames": seen.shape[0],
                           "points": seen.shape[1]}  # fmt: skip
    for label, n_key in VARIANTS.items():
        fit = max_depth_shapes(rays, seen, seed=0, n_key_images=n_key)
        shapes = np.nan_to_num(fit.shapes)
        row[label] = {
            "e3d_visible": visible_e3d(shapes, truth, seen),
            "cone_s": fit.seconds["cone"],
            "n_solves": fit.n_solves,
            "status": fit.status,
        }
        print(kind, seed, label, row[label], flush=True)
    return row


def markdown(rows: list[dict[str, Any]]) -> list[str]:
    """The results table."""
    header = ["kind", "seed", "frames x points"]
    for label in VARIANTS:
        header += [f"{label} e3D", f"{label} cone s"]
    header += ["keys 30 time / joint"]
    body = []
    for row in rows:
        cells = [row["kind"], row["seed"], f"{row['frames']} x {row['points']}"]
        for label in VARIANTS:
            cells += [f"{row[label]['e3d_visible']:.4f}", f"{row[label]['cone_s']:.0f}"]
        cells.append(f"{row['keys 30']['cone_s'] / row['joint']['cone_s']:.2f}")
        body.append(cells)
    return table(header, body)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="*", default=["cloth:2", "crease:1"],
                        help="KIND:SEED pairs")  # fmt: skip
    parser.add_argument("--frames", type=int, default=90)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--mesh", type=int, default=6000)
    parser.add_argument("--tag", default="")
    args = parser.parse_args()
    meta = provenance()
    rows = []
    for scene in args.scenes:
        kind, seed = scene.split(":")
        rows.append(run_scene(kind, int(seed), args))
        name = f"key_images{args.tag}"
        write_json(OUT / f"{name}.json", meta, settings=vars(args), rows=rows)
        body = markdown(rows)
        write_markdown(OUT / f"{name}.md", "Maximum depth by key images", meta, body)
    print("\n".join(body), flush=True)


if __name__ == "__main__":
    main()
