"""The focal length of a camera nobody named: the one under which the surface keeps its lengths.

A video filmed with an unknown camera gets the default focal length (1.2 x the larger image
side, :meth:`moju_core.cameras.intrinsics.Intrinsics.default_for`). Real cameras differ from
it by 2x either way (a phone's main camera is about 0.75 x, a webcam 0.8-1 x, a telephoto
2-3 x), and a wrong focal length bends every viewing ray by a different angle: the depths
that keep one image's edges at their lengths no longer keep another's. The maximum-depth
cone program (:func:`moju_core.priors.cone_program.solve_max_depth_cone`) fits lengths and
depths to all images at once, and its isometry residual (the mean ``|1 - ||X_fi - X_fj|| /
l_e|`` over the (image, edge) pairs, :func:`~moju_core.priors.cone_program.
isometry_residual`) measures how far its solution is from keeping them. On real sequences
filmed at close range it is smallest at the true focal length, and the whole solve is most
accurate there (docs/surface_prior.md, "Focal length from the tracks").

Where the object spans a small angle the rays hardly bend whatever the focal length (a
weak-perspective view): the residual then varies with the images and points it is measured
on more than with the focal length, and its smallest value says nothing. So the residual is
measured on :data:`N_SAMPLES` samples, each of :data:`N_IMAGES` images drawn at random and
:data:`N_ANCHORS` points spread over them, every candidate on the same samples; the estimate
is the candidate with the smallest mean residual, kept only where its paired improvement over
the default passes a one-sided t-test at :data:`SIGNIFICANCE` (where every sample is the same,
as for four images of 80 points, any improvement counts); otherwise the default is kept.

Steps and cost: the candidates are the default x 2^k, k = -1.5, -1, ..., 1 (0.42 to 2.4 x the
larger side: fields of view of 100 to 23 degrees), the best refined by a parabola in log
focal; for each, the cone program of each sample: 6 x 3 cone programs of at most ``8 x 100``
depths, about a second each, whatever F and P (O(F P) to read the tracks): 10-20 s.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy import stats

from moju_core.cameras.intrinsics import Intrinsics
from moju_core.priors.cone_program import isometry_residual, solve_max_depth_cone
from moju_core.priors.neighbour_graph import neighbour_edges, spread_anchors

__all__ = [
    "CANDIDATE_OCTAVES",
    "N_ANCHORS",
    "N_IMAGES",
    "N_SAMPLES",
    "SIGNIFICANCE",
    "FocalEstimate",
    "estimate_focal",
]

#: Candidate focal lengths: the default x 2^k for these k, half an octave apart (0.35 to 2 x
#: the default: fields of view of 100 to 23 degrees along the larger side).
CANDIDATE_OCTAVES = np.arange(-1.5, 1.01, 0.5)
#: Images of each sample, drawn at random from the sequence.
N_IMAGES = 8
#: Anchors (points) of each cone program.
N_ANCHORS = 100
#: Samples (of images and anchors): the residual's spread over them is what a difference
#: between two focal lengths is judged against.
N_SAMPLES = 3
#: Level of the one-sided paired t-test an estimate must pass to replace the default.
SIGNIFICANCE = 0.05
#: Image neighbours per anchor, as the surface prior's graph.
_K_NEIGHBOURS = 8


@dataclass(frozen=True)
class FocalEstimate:
    """The focal length chosen for a camera given only by its frame size.

    Attributes
    ----------
    intrinsics : Intrinsics
        The camera to solve with: the default one when ``accepted`` is False, else the default
        with ``focal_px`` (origin ``"estimated"``).
    candidates : ndarray of shape (C,)
        Focal lengths tried, pixels, increasing; the default among them.
    residuals : ndarray of shape (C, S)
        Isometry residual (dimensionless) per candidate and sample; inf where the cone program
        left no edge measured or the sample's images see too few points twice (a sample with
        an inf keeps the default).
    accepted : bool
        Whether the tracks preferred another focal length than the default significantly.
    seconds : float
        Wall time of the estimate.
    """

    intrinsics: Intrinsics
    candidates: np.ndarray
    residuals: np.ndarray
    accepted: bool
    seconds: float

    @property
    def focal_px(self) -> float:
        """Focal length of :attr:`intrinsics`, pixels."""
        return self.intrinsics.fx


def estimate_focal(
    W: np.ndarray, visibility: np.ndarray, default: Intrinsics, *, seed: int = 0
) -> FocalEstimate:
    """The focal length under which the isometric prior fits the tracks best, if significant.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Pixel tracks, rows ``2f``, ``2f + 1`` = x, y in frame ``f``.
    visibility : ndarray of shape (F, P), bool
    default : Intrinsics
        The camera of the frame size (principal point and skew kept; both focal lengths set
        to each candidate).
    seed : int
        Seed of the first anchor sample (sample ``s`` uses ``seed + s``).
    """
    start = time.perf_counter()
    candidates = default.fx * 2.0**CANDIDATE_OCTAVES
    rng = np.random.default_rng(seed)
    residuals = np.full((candidates.size, N_SAMPLES), np.inf)
    for s in range(N_SAMPLES):
        pixels, seen = _sample(W, visibility, rng)
        if seen.shape[1] <= _K_NEIGHBOURS:  # too few points seen twice: nothing measured
            continue
        rays = _rays(pixels, seen, default)
        anchors = spread_anchors(rays, seen, n_anchor=N_ANCHORS, seed=seed + s)
        pixels, seen = pixels[:, anchors], seen[:, anchors]
        edges = neighbour_edges(rays[:, anchors], seen, k=_K_NEIGHBOURS)
        for c, focal in enumerate(candidates):
            camera = default.with_focal(focal, "given")
            residuals[c, s] = _residual(_rays(pixels, seen, camera), seen, edges)
    best, accepted = _choice(residuals, int(np.argmin(np.abs(CANDIDATE_OCTAVES))))
    refined = _refined(candidates, residuals.mean(axis=1), best) if accepted else None
    intrinsics = default if refined is None else default.with_focal(refined, "estimated")
    return FocalEstimate(intrinsics, candidates, residuals, accepted, time.perf_counter() - start)


def _sample(
    W: np.ndarray, visibility: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions (n, P', 2) and visibility (n, P') of :data:`N_IMAGES` images drawn at
    random from W (2F, P) (all of them when F is no larger), for the P' points two of them
    see."""
    n_frames, n_points = visibility.shape
    images = np.sort(rng.choice(n_frames, min(N_IMAGES, n_frames), replace=False))
    seen = visibility[images]
    points = np.flatnonzero(seen.sum(axis=0) >= 2)
    pixels = W.reshape(n_frames, 2, n_points).transpose(0, 2, 1)[images]
    return pixels[:, points], seen[:, points]


def _rays(pixels: np.ndarray, seen: np.ndarray, camera: Intrinsics) -> np.ndarray:
    """(n, P, 2) normalised coordinates of ``pixels`` (n, P, 2) under ``camera``, NaN where
    not ``seen`` (n, P)."""
    n_images, n_points, _ = pixels.shape
    W = pixels.transpose(0, 2, 1).reshape(2 * n_images, n_points)
    rays = camera.normalise(W).reshape(n_images, 2, n_points).transpose(0, 2, 1)
    return np.where(seen[:, :, None], rays, np.nan)


def _residual(rays: np.ndarray, seen: np.ndarray, edges: np.ndarray) -> float:
    """The isometry residual of the cone program's solution on ``rays`` (n, A, 2)."""
    solution = solve_max_depth_cone(rays, seen, edges, length_scale="edges")
    residual = isometry_residual(rays, edges, solution.depths, solution.lengths)
    return residual if np.isfinite(residual) else np.inf


def _choice(residuals: np.ndarray, default: int) -> tuple[int, bool]:
    """The candidate with the smallest mean residual over the samples (C, S), and whether its
    improvement over candidate ``default`` is significant (one-sided paired t-test at
    :data:`SIGNIFICANCE`; where the samples agree exactly, or the default measured nothing
    in one, any improvement)."""
    mean = residuals.mean(axis=1)
    best = int(np.argmin(mean))
    if best == default or not np.isfinite(mean[best]):
        return default, False
    gain = residuals[default] - residuals[best]  # (S,): inf where the default failed
    spread = np.std(gain, ddof=1) if np.all(np.isfinite(gain)) else 0.0
    if spread == 0.0:
        return best, bool(np.mean(gain) > 0)
    t = np.mean(gain) / (spread / np.sqrt(gain.size))
    return best, bool(t > stats.t.ppf(1.0 - SIGNIFICANCE, gain.size - 1))


def _refined(candidates: np.ndarray, mean: np.ndarray, best: int) -> float:
    """The focal length at the vertex of the parabola in log focal through candidate ``best``
    and its two neighbours (kept within them); the candidate itself at either end of the
    grid or where the three are not convex."""
    if best in (0, candidates.size - 1) or not np.all(np.isfinite(mean[best - 1 : best + 2])):
        return float(candidates[best])
    below, here, above = mean[best - 1 : best + 2]
    curvature = below - 2.0 * here + above
    if curvature <= 0.0:
        return float(candidates[best])
    step = np.log(candidates[best + 1] / candidates[best])
    offset = 0.5 * (below - above) / curvature  # in steps, within [-0.5, 0.5] when convex
    return float(candidates[best] * np.exp(np.clip(offset, -1.0, 1.0) * step))
