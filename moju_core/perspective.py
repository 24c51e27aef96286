"""Tracks filmed by a known camera: depth from the isometric surface prior, the loop on top.

Real footage is mostly a static or hand-held camera and an object that turns 10-30 degrees:
too little rotation for depth from motion, and an orthographic model explains the object's
motion towards and away from the camera as deformation. With the camera's intrinsics K the
solve instead

0. estimates the focal length where K is only the default of the frame size
   (:func:`solving_camera`, :func:`moju_core.priors.focal_length.estimate_focal`);
1. maps the pixel tracks to viewing rays (:meth:`moju_core.cameras.intrinsics.Intrinsics.
   normalise`);
2. finds the depth of every point along its ray by the maximum-depth heuristic of an
   inextensible surface (:func:`moju_core.priors.max_depth.max_depth_shapes`): per-image 3D
   shapes in each image's camera frame, one scale for the sequence (mean depth 1), no camera
   rotation needed;
3. runs the MoJu loop on those shapes in the camera frame (rotations ``[I_2 0]``, the tracks
   the shapes' x and y), with the data term anchored to the prior's shapes
   (:class:`moju_core.loop.data_terms.AnchoredTerm`): the low-rank model and the local groups
   regularise them, the anchor keeps the depths the tracks cannot set.

Hidden entries have no ray depth: the prior's shape of a hidden point is taken from the three
nearest frames that see it, each moved by the rigid motion of the points both frames see, and
the median of the three kept (where those frames share no point with its frame, from the frames
filled so, in a second pass). Costs:
those of the prior (a cone program on a few hundred anchors, then an interpolation of the
other points' depths from m = 8 anchors each, O(F P (m + log A))) and of the loop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from moju_core import defaults
from moju_core.cameras.intrinsics import Intrinsics
from moju_core.errors import MeasurementError
from moju_core.loop import admm, lrr
from moju_core.loop.data_terms import AnchoredTerm
from moju_core.params import SolverParams
from moju_core.priors.dense_depth import homogeneous
from moju_core.priors.focal_length import estimate_focal
from moju_core.priors.max_depth import SurfaceFit, max_depth_shapes
from moju_core.spectrum import noise_variance, significant_rank, spectrum

if TYPE_CHECKING:
    from collections.abc import Callable

    from moju_core.result import Result

#: Weight of the pull towards the prior's shapes, relative to the data term of the
#: scale-normalised tracks: as much as the tracks themselves, so that neither the prior nor the
#: low-rank model alone sets the depths.
ANCHOR_WEIGHT = 1.0

#: Relative size of the second singular value below which points lie on a line and fix no
#: rotation (rounding level of a cross-covariance).
RCOND_MOTION = 1e-9

#: Frames a hidden point is taken from: the fewest whose median rejects one wrong source (a
#: track is least reliable in the frames just before it is lost, where the surface turns away).
FILL_SOURCES = 3


def uses_surface_prior(params: SolverParams, intrinsics: Intrinsics | None) -> bool:
    """Whether a solve takes the perspective path: ``surface_prior`` ``"isometric"``, or
    ``"auto"`` with a known camera, estimated rotations (known rotations are an orthographic
    camera's) and an iterative method (``pta`` is a closed-form orthographic fit). Refused
    where it cannot run: without a camera (the prior needs viewing rays), or with method
    ``pta``."""
    if params.surface_prior == "none":
        return False
    if params.surface_prior == "isometric":
        if intrinsics is None:
            raise MeasurementError(
                "surface_prior='isometric' needs the camera's intrinsics (pixel tracks and K): "
                "pass intrinsics=, or --intrinsics FILE / --focal PIXELS on the command line"
            )
        if params.method == "pta":
            raise MeasurementError(
                "surface_prior='isometric' runs the loop of an iterative method; method "
                "'pta' is a closed-form orthographic fit: choose another method, or "
                "surface_prior='none'"
            )
    return intrinsics is not None and params.method != "pta" and params.rotations != "known"


def solving_camera(
    W: np.ndarray, visibility: np.ndarray, intrinsics: Intrinsics, seed: int
) -> Intrinsics:
    """The camera the perspective solve uses: ``intrinsics`` as given, except the default
    camera of a frame size (origin ``"default"``: nobody named one), whose focal length is
    estimated from the tracks ``W`` (2F, P) pixels, ``visibility`` (F, P)
    (:func:`moju_core.priors.focal_length.estimate_focal`: origin ``"estimated"``, or
    ``"default"`` still where the tracks do not tell)."""
    if intrinsics.origin != "default":
        return intrinsics
    return estimate_focal(W, visibility, intrinsics, seed=seed).intrinsics


def used_camera(given: Intrinsics, result: Result) -> Intrinsics:
    """The camera the solve ``result`` of pixels with the camera ``given`` used, from its plan
    (:attr:`moju_core.result.Diagnostics.plan`): ``given`` with the estimated focal length
    where the solve estimated one, else ``given``."""
    plan = result.diagnostics.plan if result.diagnostics is not None else None
    if plan is None or plan.focal_origin != "estimated" or plan.focal_px is None:
        return given
    return given.with_focal(plan.focal_px, "estimated")


def prior_shapes(
    W: np.ndarray, visibility: np.ndarray, intrinsics: Intrinsics, seed: int
) -> tuple[np.ndarray, SurfaceFit]:
    """Per-image camera-frame shapes (F, P, 3) of the isometric prior, every entry filled.

    ``W`` (2F, P) in pixels, ``visibility`` (F, P) bool. A point the prior leaves without
    a depth in an image, hidden or seen (a seen point with no neighbour seen with it, or cut
    off from the rest of the surface in that image), is taken from the nearest images that
    have it (:func:`_fill_hidden`); a seen one is then moved to the nearest point of its ray
    (:func:`_unplaced_on_rays`).
    """
    n_frames, n_points = visibility.shape
    rays = intrinsics.normalise(W).reshape(n_frames, 2, n_points).transpose(0, 2, 1)
    rays = np.where(visibility[:, :, None], rays, np.nan)
    fit = max_depth_shapes(rays, visibility, seed=seed)
    if not np.isfinite(fit.depths).any():
        raise MeasurementError(_unsolved_prior_message(fit.status, rays, intrinsics))
    depths = _place_empty_frames(fit.depths, visibility)
    placed = np.isfinite(depths)
    points = homogeneous(rays)
    shapes = _fill_hidden(depths[:, :, None] * points, placed)
    return _unplaced_on_rays(shapes, points, visibility & ~placed, depths), fit


def _place_empty_frames(depths: np.ndarray, visibility: np.ndarray) -> np.ndarray:
    """``depths`` (F, P) with the seen points of every image in which the prior placed none
    (all its seen points cut off from one another, as when the object has almost left the
    view) put at the median depth of the nearest image that has placed points (the earlier
    one at equal distance): without a placed point an image has nothing to move its hidden
    points by. Unchanged when every image has one; at least one image must. O(F P)."""
    empty = ~np.isfinite(depths).any(axis=1) & visibility.any(axis=1)
    if not empty.any():
        return depths
    has = np.flatnonzero(np.isfinite(depths).any(axis=1))
    nearest = has[np.argmin(np.abs(np.arange(len(depths))[:, None] - has[None, :]), axis=1)]
    median = np.nanmedian(depths[nearest], axis=1)
    return np.where(empty[:, None] & visibility, median[:, None], depths)


def _unplaced_on_rays(
    shapes: np.ndarray, homogeneous: np.ndarray, unplaced: np.ndarray, depths: np.ndarray
) -> np.ndarray:
    """``shapes`` (F, P, 3) with each ``unplaced`` (F, P) seen point moved to the nearest
    point of its ray ``homogeneous`` (F, P, 3, ``[x', y', 1]``); at the median seen depth
    of its image (``depths`` (F, P), NaN where not placed) where no image placed it or its
    position is behind the camera. O(F P)."""
    if not unplaced.any():
        return shapes
    along = _along_rays(shapes, homogeneous)
    median = np.nanmedian(depths, axis=1)[:, None]
    along = np.where(np.isfinite(along) & (along > 0), along, median)
    return np.where(unplaced[:, :, None], along[:, :, None] * homogeneous, shapes)


def _unsolved_prior_message(status: str, rays: np.ndarray, intrinsics: Intrinsics) -> str:
    """What to do when the cone program placed no point: usually a focal length so long that
    the tracks span almost no angle, where a perspective camera is an orthographic one."""
    view = float(np.degrees(2.0 * np.arctan(np.nanmax(np.abs(rays)))))
    return (
        f"the surface prior found no depth (cone solver status {status!r}); the tracks span "
        f"a field of view of {view:.3g} degrees with the focal length "
        f"{intrinsics.K[0, 0]:.6g} px. Check the focal length (in pixels, about the image "
        "width for an ordinary lens), or reconstruct without intrinsics (orthographic) or "
        "with surface_prior='none'"
    )


def _fill_hidden(shapes: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Points without a shape (``~known``, (F, P)) from the :data:`FILL_SOURCES` nearest frames
    that have them, each moved by the object's rigid motion between the two frames
    (:func:`_rigid_motion` of the points both frames have), and the median of those
    positions, coordinate by coordinate (fewer sources where the point is seen in fewer
    frames). A source that shares no point with the frame gives no motion; an entry left
    without a position for that reason is taken in a second pass from the nearest frames
    that have one after the first, moved by the frame's own points. O(F P) per pair of
    frames, at most ``FILL_SOURCES`` sources per frame and point and pass.
    """
    if known.all():
        return shapes
    filled = _fill_pass(shapes, known, known)
    filled_entries = np.isfinite(filled).all(axis=2)
    if filled_entries.all() or not (filled_entries & ~known).any():
        return filled
    return _fill_pass(filled, filled_entries, known)


def _fill_pass(shapes: np.ndarray, available: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """One pass of :func:`_fill_hidden`: the entries not ``available`` (F, P) from the nearest
    frames where they are, moved by the rigid motion of the points that are ``anchors`` (F, P)
    in the frame and available in the source."""
    filled = shapes.copy()
    sources = _nearest_known(available, FILL_SOURCES)
    for frame in range(available.shape[0]):
        todo = np.flatnonzero(~available[frame] & (sources[0, frame] >= 0))
        if todo.size:
            moved = _moved_to(frame, todo, sources[:, frame, todo], shapes, available, anchors)
            filled[frame, todo] = np.nanmedian(moved, axis=0)
    return filled


def _moved_to(
    frame: int,
    points: np.ndarray,
    sources: np.ndarray,
    shapes: np.ndarray,
    available: np.ndarray,
    anchors: np.ndarray,
) -> np.ndarray:
    """``points`` (n,) as seen in each of their ``sources`` (S, n) (-1: none), moved into
    ``frame`` by the rigid motion of the points that are ``anchors`` in the frame and
    ``available`` in the source: (S, n, 3), NaN where there is no source or no such point."""
    moved = np.full(sources.shape + (3,), np.nan)
    for source in np.unique(sources[sources >= 0]):
        both = anchors[frame] & available[source]
        if not both.any():
            continue
        rotation, shift = _rigid_motion(shapes[source, both], shapes[frame, both])
        rank, column = np.nonzero(sources == source)
        moved[rank, column] = shapes[source, points[column]] @ rotation.T + shift
    return moved


def _nearest_known(known: np.ndarray, n_sources: int) -> np.ndarray:
    """For each entry (F, P), the ``n_sources`` nearest frames in which its point is known,
    nearest first, the earlier frame first at equal distance ((n_sources, F, P); -1: none)."""
    n_frames = known.shape[0]
    frames = np.arange(n_frames)
    nearest = np.full((n_sources,) + known.shape, -1, dtype=np.int64)
    for point in np.flatnonzero(~known.all(axis=0) & known.any(axis=0)):
        seen = np.flatnonzero(known[:, point])
        order = np.argsort(np.abs(frames[:, None] - seen[None, :]), axis=1, kind="stable")
        ranked = seen[order[:, :n_sources]]  # (F, min(n_sources, seen))
        nearest[: ranked.shape[1], :, point] = ranked.T
    return nearest


def _rigid_motion(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) taking the points ``source`` (n, 3) closest to
    ``target`` (n, 3) in least squares (Kabsch, no reflection). Only the translation when
    the points do not fix a rotation (fewer than three, or all on a line)."""
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    covariance = (source - source_mean).T @ (target - target_mean)
    u, singular, vt = np.linalg.svd(covariance)
    rotation = np.eye(3)
    if len(source) >= 3 and singular[1] > RCOND_MOTION * singular[0]:
        mirror = np.sign(np.linalg.det(u @ vt))
        rotation = (u * [1.0, 1.0, mirror]) @ vt
        rotation = rotation.T
    return rotation, target_mean - rotation @ source_mean


def refine_on_prior(
    prior: np.ndarray,
    visibility: np.ndarray,
    params: SolverParams,
    hook: Callable[[int, float, float], bool] | None = None,
) -> tuple[np.ndarray, admm.LoopOutput, SolverParams, float]:
    """The MoJu loop in the camera frame, anchored to the prior's shapes (F, P, 3).

    Returns the refined shapes (F, P, 3) in the prior's frame and units (seen entries on their
    viewing rays at the loop's depth, :func:`_onto_rays`; hidden entries moved from the nearest
    frames that see them, as in :func:`prior_shapes`), the loop's output,
    the resolved parameters and the noise variance of the loop's tracks (relative to their
    mean square).
    """
    n_frames, n_points, _ = prior.shape
    centroid = prior.mean(axis=1, keepdims=True)
    centred = (prior - centroid).transpose(0, 2, 1)  # (F, 3, P)
    scale = float(np.sqrt(np.mean(centred[:, :2] ** 2)))
    centred = centred / scale
    tracks = np.ascontiguousarray(centred[:, :2])
    rotations = np.broadcast_to(np.eye(2, 3), (n_frames, 2, 3)).copy()
    flat_tracks = tracks.reshape(2 * n_frames, n_points)
    singular = spectrum(flat_tracks).singular
    top = lrr.top_singular_value(centred.reshape(n_frames, 3 * n_points))
    if params.smoothness is None:
        params = params.model_copy(update={"smoothness": 0.0})
    noise = noise_variance(singular, flat_tracks.shape)
    params = defaults.resolve(
        params,
        n_frames,
        n_points,
        top,
        rotations=rotations,
        noise=noise,
        signal_rank=significant_rank(singular, flat_tracks.shape),
    )
    observed = None if visibility.all() else visibility
    term = AnchoredTerm.over(n_frames, n_points, observed, anchor=centred, weight=ANCHOR_WEIGHT)
    out = admm.run(tracks, admm.LoopCameras(rotations), params, term, hook=hook)
    shapes = _onto_rays(out.shapes.transpose(0, 2, 1) * scale + centroid, prior)
    if observed is not None:
        # The loop's low-rank model places hidden points worse than the rigid motion of the
        # refined seen points does (docs/surface_prior.md): refill them from those.
        shapes = _fill_hidden(np.where(visibility[:, :, None], shapes, np.nan), visibility)
    return shapes, out, params, float(noise)


def _onto_rays(shapes: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """Each point of ``shapes`` (F, P, 3) moved to the nearest point of its viewing ray, the
    ray through the prior's point (F, P, 3; on its ray where seen), so that the loop sets
    depths and the tracks alone set where the points are seen. O(F P)."""
    rays = prior / prior[:, :, 2:3]
    return _along_rays(shapes, rays)[:, :, None] * rays


def _along_rays(shapes: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Parameter ``t`` (F, P) of the point ``t * ray`` nearest to each point of ``shapes``
    (F, P, 3), ``rays`` (F, P, 3) with z = 1 (so ``t`` is a depth). O(F P)."""
    return np.sum(shapes * rays, axis=2) / np.sum(rays**2, axis=2)
