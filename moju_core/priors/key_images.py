"""The maximum-depth cone program over many images: lengths from key images, then the rest.

The images of :func:`~moju_core.priors.cone_program.solve_max_depth_cone` are coupled only
through the edge lengths ``l_e`` they share. Solved jointly, every image's cones meet the same
length columns, and the interior-point factorisation grows faster than the number of images
``F`` (see ``docs/surface_prior.md``, Timings). Given the lengths, the images are independent
and the program is block-diagonal, so its cost is linear in ``F``. Hence:

1. key images: :data:`MAX_KEY_IMAGES` spread evenly over the sequence, then more, one at a
   time, until every edge seen whole in some image is seen whole in a key image (each
   length is then set by the data);
2. the joint program on the key images sets the lengths (mean 1) and their depths;
3. every other image is solved alone with those lengths fixed (a program of ``O(A k)``
   cones each).

A sequence of at most :data:`MAX_KEY_IMAGES` images is solved jointly, as before.
Cost: the joint program on ``min(F, MAX_KEY_IMAGES)`` images (``O(A k)`` cones each, ``A``
points, ``k`` neighbours) plus ``O(F A k)`` for the rest.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from moju_core.priors.cone_program import ConeSolution, solve_max_depth_cone

__all__ = ["MAX_KEY_IMAGES", "key_images", "solve_by_key_images"]

#: Images solved jointly: a cost bound (the joint program's time grows faster than its number
#: of images: about 1.5 minutes for 30 images of 200 points on the shared machine), and as
#: many images as the rendered footage has, whose results it leaves unchanged.
MAX_KEY_IMAGES = 30


def key_images(seen: np.ndarray, edges: np.ndarray, n_key: int = MAX_KEY_IMAGES) -> np.ndarray:
    """Indices (sorted) of the key images: ``n_key`` evenly spaced, then greedily those that
    see the most edges no key image sees whole, until none is left.

    ``seen`` (F, P) bool, ``edges`` (E, 2) int. Cost ``O(F E)`` per image added.
    """
    n_frames = seen.shape[0]
    whole = seen[:, edges[:, 0]] & seen[:, edges[:, 1]]  # (F, E)
    chosen = set(np.unique(np.linspace(0, n_frames - 1, min(n_key, n_frames)).round().astype(int)))
    needed = whole.any(axis=0)
    while True:
        missing = needed & ~whole[sorted(chosen)].any(axis=0)
        if not missing.any():
            return np.array(sorted(chosen), dtype=np.int64)
        chosen.add(int(np.argmax(whole[:, missing].sum(axis=1))))


def solve_by_key_images(
    rays: np.ndarray,
    seen: np.ndarray,
    edges: np.ndarray,
    *,
    n_key: int = MAX_KEY_IMAGES,
    **options: Any,
) -> ConeSolution:
    """The maximum-depth program of all images, by key images and fixed lengths.

    ``rays`` (F, P, 2), ``seen`` (F, P) bool, ``edges`` (E, 2) int and ``options``
    (``rigidity``, ``outlier_price``, ...) as in
    :func:`~moju_core.priors.cone_program.solve_max_depth_cone`, whose result this returns
    for all images (``status`` the first that is not ``"Solved"``, counts summed). At most
    ``n_key`` images (plus any needed to see every edge) are solved jointly.
    """
    n_frames = seen.shape[0]
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if n_frames <= n_key:
        return solve_max_depth_cone(rays, seen, edges, **options)
    start = time.perf_counter()
    keys = key_images(seen, edges, n_key)
    joint = solve_max_depth_cone(rays[keys], seen[keys], edges, **options)
    rest = np.setdiff1d(np.arange(n_frames), keys)
    known = np.isfinite(joint.lengths)
    depths = np.full(seen.shape, np.nan)
    depths[keys] = joint.depths
    solves = [joint]
    for frame in rest:
        alone = solve_max_depth_cone(
            rays[frame : frame + 1], seen[frame : frame + 1], edges[known],
            lengths=joint.lengths[known], **options,
        )  # fmt: skip
        depths[frame] = alone.depths[0]
        solves.append(alone)
    return _combined(solves, depths, joint.lengths, time.perf_counter() - start)


def _combined(
    solves: list[ConeSolution], depths: np.ndarray, lengths: np.ndarray, seconds: float
) -> ConeSolution:
    """One solution from the joint solve (first) and the single images' solves."""
    failed = [s.status for s in solves if s.status != "Solved"]
    n_cones = np.array([s.n_cones for s in solves])
    shrink = np.array([s.shrink for s in solves])
    return ConeSolution(
        depths=depths,
        lengths=lengths,
        status=failed[0] if failed else "Solved",
        seconds=seconds,
        n_cones=int(n_cones.sum()),
        n_solves=sum(s.n_solves for s in solves),
        shrink=float(shrink @ n_cones / max(n_cones.sum(), 1)),
        length_scale=solves[0].length_scale,
    )
