"""Where the perspective solve of one footage scene goes wrong: prior or loop, seen or hidden.

Renders and tracks one scene as ``benchmarks/footage.py`` does, then runs the two stages of
the perspective solve (``perspective.prior_shapes`` then ``perspective.refine_on_prior``,
default parameters, seed 0) on the tracks and on perfect tracks of the same points, and
prints per frame (every third): the visible share, ``scaled_e3d`` over every point and over
the visible ones, the estimate's largest depth over its median (the truth's beside it), and
for the frames whose prior has depths above 1.5 x the median, those points' track errors::

    PYTHONPATH=. nice python benchmarks/footage_prior_diagnosis.py crease 1
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from footage import scene_video  # noqa: E402
from tracking import perfect_tracks  # noqa: E402

from moju_core import SolverParams, perspective  # noqa: E402
from moju_core.datasets.totem import scaled_e3d  # noqa: E402
from moju_core.footage.perspective_render import project  # noqa: E402
from moju_core.footage.tracking import track_frames  # noqa: E402

WILD = 1.5


def per_frame(shapes: np.ndarray, truth: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(F, 2) scaled e3D of every frame over all points and over the seen ones."""
    return np.array([
        [scaled_e3d(shapes[f : f + 1], truth[f : f + 1]),
         scaled_e3d(shapes[f : f + 1, s], truth[f : f + 1, s])]
        for f, s in enumerate(seen)
    ])  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("kind")
    parser.add_argument("seed", type=int)
    parser.add_argument("--frames", type=int, default=30)
    args = parser.parse_args()
    args.width, args.height, args.mesh = 640, 480, 6000
    _, video = scene_video(args.kind, args.seed, args)
    camera = video.intrinsics
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        kept, perfect, index = perfect_tracks(
            video, track_frames(list(video.frames), mask=video.mask)
        )
    truth = video.paths_3d[:, index]
    every = slice(None, None, 3)
    print("visible share", np.round(kept.visibility.mean(axis=1)[every], 2))
    ratio = truth[..., 2].max(axis=1) / np.median(truth[..., 2], axis=1)
    print("truth depth max / median", np.round(ratio[every], 2))
    for label, source in (("perfect", perfect), ("tracks", kept)):
        prior, _ = perspective.prior_shapes(source.W, source.visibility, camera, 0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            shapes, *_ = perspective.refine_on_prior(prior, source.visibility, SolverParams(seed=0))
        print(f"{label}: e3D prior {scaled_e3d(prior, truth):.4f}, "
              f"prior + loop {scaled_e3d(shapes, truth):.4f}")  # fmt: skip
        errors = per_frame(shapes, truth, source.visibility)
        print("  per frame, all points ", np.round(errors[every, 0], 3))
        print("  per frame, seen points", np.round(errors[every, 1], 3))
        depth = shapes[..., 2]
        print("  depth max / median", np.round((depth.max(1) / np.median(depth, 1))[every], 2))
        error = np.linalg.norm(project(prior, camera.K) - video.paths_2d[:, index], axis=2)
        for f in range(video.n_frames):
            seen = source.visibility[f]
            wild = seen & (prior[f, :, 2] > WILD * np.median(prior[f, seen, 2]))
            if wild.any():
                print(f"  frame {f}: {wild.sum()} seen points deeper than {WILD} x the median "
                      f"(up to {prior[f, wild, 2].max() / np.median(prior[f, seen, 2]):.1f} x); "
                      f"their track errors {np.round(np.sort(error[f, wild])[::-1][:6], 2)} px, "
                      f"the others' median {np.median(error[f, seen & ~wild]):.3f} px")  # fmt: skip


if __name__ == "__main__":
    main()
