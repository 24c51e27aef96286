"""The solver's camera step: one entry point over the rotation estimators, and ``"auto"``.

* ``"intersection"``: Dai, Li and He's method
  (:func:`moju_core.cameras.intersection.intersection_rotations`), the paper's choice. It is
  exact when the shapes are combinations of a few shape bases, as faces nearly are.
* ``"windowed"``: rigid factorisations of short windows of frames, chained
  (:mod:`moju_core.cameras.windowed`); right when the camera turns fast compared with the
  deformation, whatever the shapes. Approximate: the ADMM loop refines them with the shapes.
* ``"rigid"``: Tomasi and Kanade (:func:`moju_core.cameras.rigid.rigid_rotations`).
* ``"plane"``: the calibration of the object's dominant plane, fitted robustly to groups of
  tracks (:mod:`moju_core.cameras.plane`); for sheets (flags, bumpy surfaces), whose depth is
  mostly deformation. Not refined by the loop, and not chosen by ``"auto"``.
* ``"auto"`` (default): the intersection rotations, unless the windowed ones explain the
  tracks as rigid over every three frames with less than a third of the deformation the
  intersection rotations leave (after removing what the noise of the tracks accounts for).
  Both are right when the object is nearly rigid over three frames; the intersection
  estimate breaks down when the shape bases do not hold (measured on the synthetic rolling
  sheet and waving cloth: 36-79 degrees of error, against 12-25 degrees for the windowed
  chain before refinement), and then it leaves many times more deformation within three
  frames (10-100 times on those sheets without noise; at most 2.2 times on the faces, where
  the intersection rotations are the better ones).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from moju_core.cameras.bases import check_measurements, choose_n_bases
from moju_core.cameras.intersection import intersection_estimate
from moju_core.cameras.plane import DEFAULT_GROUPS, plane_rotations
from moju_core.cameras.rigid import rigid_rotations
from moju_core.cameras.windowed import (
    RIGIDITY_WINDOW,
    WINDOW_LENGTHS,
    RowGram,
    best_windowed_rotations,
    short_time_rigidity,
)
from moju_core.result import RotationSource
from moju_core.spectrum import Spectrum, noise_variance, spectrum

__all__ = ["AUTO_MARGIN", "CameraEstimate", "estimate_cameras"]

#: ``"auto"`` takes the windowed rotations when their deformation over three frames (beyond
#: the noise) is below this fraction of the intersection rotations': a clear margin, since
#: rotations fitted rigidly to short windows absorb part of the deformation and so look more
#: rigid than they are.
AUTO_MARGIN = 1.0 / 3.0


@dataclass(frozen=True)
class CameraEstimate:
    """Rotations and how they were obtained.

    rotations : ndarray of shape (F, 2, 3)
    source : {"known", "intersection", "windowed", "rigid", "plane"}
        Where the rotations come from (:data:`moju_core.result.RotationSource`); ``"rigid"``
        also when the intersection method fell back to the rigid rotations.
    n_bases : int or None
        Shape bases of the intersection method, when it ran.
    window : int or None
        Window length of the windowed estimate, when it was chosen.
    refine : bool
        Whether the ADMM loop should refine the rotations with the shapes (windowed).
    rigidity : dict of str to float
        :func:`moju_core.cameras.windowed.short_time_rigidity` of the candidates that were
        compared (``"auto"`` only), noise part removed.
    smoothing : float
        Weight of :func:`moju_core.cameras.smoothing.smooth_rotations` on given rotations
        (``"known"`` only); 0 when they were used as given.
    """

    rotations: np.ndarray
    source: RotationSource
    n_bases: int | None = None
    window: int | None = None
    refine: bool = False
    rigidity: dict[str, float] | None = None
    smoothing: float = 0.0


def estimate_cameras(
    W: np.ndarray,
    method: str,
    *,
    n_bases: int | None = None,
    seed: int = 0,
    decomposition: Spectrum | None = None,
    n_groups: int | None = None,
) -> CameraEstimate:
    """Camera rotations of centred tracks by the named method.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Centred (and scale-normalised) measurements.
    method : {"auto", "intersection", "windowed", "rigid", "plane"}
    n_bases : int, optional
        Shape bases of the intersection method; chosen from the spectrum when omitted.
    seed : int, default 0
        Seed of the intersection method's search.
    decomposition : Spectrum, optional
        ``spectrum(W)``, if already computed (it is computed once otherwise).
    n_groups : int, optional
        Groups of tracks of the plane estimator (``"plane"`` only);
        :data:`moju_core.cameras.plane.DEFAULT_GROUPS` when omitted (``docs/cameras.md``).

    Returns
    -------
    CameraEstimate
    """
    if method == "rigid":
        return CameraEstimate(rigid_rotations(W), "rigid")
    if method == "plane":
        if decomposition is None:
            decomposition = spectrum(check_measurements(W))
        variance = noise_variance(decomposition.singular, W.shape)
        rotations = plane_rotations(
            W,
            n_groups=DEFAULT_GROUPS if n_groups is None else n_groups,
            noise_variance=variance,
            seed=seed,
        )
        return CameraEstimate(rotations, "plane")  # type: ignore[arg-type]
    if method not in ("auto", "intersection", "windowed"):
        raise ValueError(f"unknown rotation method {method!r}")
    if method == "windowed":
        gram = RowGram(W, max(WINDOW_LENGTHS))
        rigid = rigid_rotations(W)
        rotations, window, _ = best_windowed_rotations(gram, rigid)
        return CameraEstimate(rotations, "windowed", window=window, refine=True)
    if decomposition is None:
        decomposition = spectrum(check_measurements(W))
    if n_bases is None:
        n_bases = choose_n_bases(W, singular=decomposition.singular)
    if method == "intersection" or W.shape[0] < 2 * RIGIDITY_WINDOW:
        intersection, rigid = intersection_estimate(
            W, n_bases, seed=seed, decomposition=decomposition
        )
        return CameraEstimate(intersection, _source(rigid), n_bases=n_bases)
    # The intersection method's warnings (e.g. that no shape basis fits) matter only if its
    # rotations are kept.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        intersection, fell_back = intersection_estimate(
            W, n_bases, seed=seed, decomposition=decomposition
        )
    gram = RowGram(W, max(WINDOW_LENGTHS))
    rigid = rigid_rotations(W)
    windowed, window, windowed_rigidity = best_windowed_rotations(gram, rigid)
    singular = decomposition.singular
    # Noise of variance sigma^2 leaves sigma^2 / 2 of every entry's energy unexplained.
    noise_part = 0.5 * noise_variance(singular, W.shape) * W.size / max(gram.total, 1e-300)
    excess = {
        "intersection": max(short_time_rigidity(gram, intersection) - noise_part, 0.0),
        "windowed": max(windowed_rigidity - noise_part, 0.0),
    }
    if excess["windowed"] < AUTO_MARGIN * excess["intersection"]:
        return CameraEstimate(
            windowed, "windowed", n_bases=n_bases, window=window, refine=True, rigidity=excess
        )
    for warning in caught:
        warnings.warn(warning.message, warning.category, stacklevel=2)
    return CameraEstimate(intersection, _source(fell_back), n_bases=n_bases, rigidity=excess)


def _source(rigid: bool) -> RotationSource:
    """What the intersection method's rotations are: its own, or its rigid fallback."""
    return "rigid" if rigid else "intersection"
