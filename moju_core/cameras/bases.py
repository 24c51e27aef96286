"""How many shape bases the measurements support, and the checks of W for the camera estimators.

Under the low-rank shape model ``S_f = sum_k c_fk B_k`` the measurements ``W = Pi B`` have rank
at most 3K. :func:`choose_n_bases` reads K off the numerical rank of W
(:func:`moju_core.spectrum.significant_rank`); :func:`min_frames_for_bases` and
:func:`check_n_bases` (both defined in :mod:`moju_core.feasibility`) say which K a sequence
of F frames and P points can determine.
"""

from __future__ import annotations

import math

import numpy as np

from moju_core import feasibility, validation
from moju_core.feasibility import min_frames_for_bases
from moju_core.spectrum import significant_rank, spectrum

__all__ = ["check_measurements", "check_n_bases", "choose_n_bases", "min_frames_for_bases"]


def check_measurements(W: np.ndarray) -> np.ndarray:
    """W (2F, P) as C-contiguous float64, checked for the camera estimators.

    The one validator of W (:func:`moju_core.validation.check_measurements`: complete tracks,
    NaN refused, since a factorisation needs every entry), and at least the frames an estimate
    needs (:func:`moju_core.feasibility.check_rotation_frames`).

    Raises
    ------
    MeasurementError
        If W is not 2-D, has an odd number of rows, holds NaN or infinite values, or has
        fewer than 3 frames.
    """
    W = validation.check_measurements(W)
    feasibility.check_rotation_frames(W.shape[0] // 2)
    return W


def check_n_bases(n_bases: int, n_frames: int, n_points: int) -> None:
    """Check that F frames of P points can determine the rotations with K shape bases.

    Parameters
    ----------
    n_bases : int
        Number of shape bases K.
    n_frames, n_points : int
        F and P of the measurements.

    Raises
    ------
    ValueError
        If ``n_bases`` is not a positive integer.
    MeasurementError
        If there are fewer than :func:`min_frames_for_bases` frames, or fewer than 3K + 1
        points (a rank-3K factorisation of centred columns).
    """
    feasibility.check_n_bases(n_bases, n_frames, n_points)


def _n_bases_from_spectrum(s: np.ndarray, shape: tuple[int, int], max_bases: int) -> int:
    """The rule of :func:`choose_n_bases` applied to given singular values (decreasing)."""
    n_rows, n_points = shape
    n_bases = math.ceil(significant_rank(s, shape) / 3)
    # Bounds: enough frames for the intersection constraints, enough points for the rank.
    by_frames = max(k for k in range(1, max_bases + 1) if min_frames_for_bases(k) <= n_rows // 2)
    by_points = (n_points - 1) // 3
    return max(1, min(n_bases, max_bases, by_frames, by_points))


def choose_n_bases(
    W: np.ndarray, max_bases: int = 10, *, singular: np.ndarray | None = None
) -> int:
    """Number of shape bases K from the singular values of W.

    W = Pi B has rank at most 3K, so K is read off the numerical rank r of W:

    1. *Rank.* r counts the singular values above the Gavish-Donoho optimal hard threshold
       for white noise of unknown level, ``omega(beta) * median(s)`` (Gavish and Donoho,
       "The optimal hard threshold for singular values is 4/sqrt(3)", IEEE Trans. Inf.
       Theory 2014; ``beta`` is the aspect ratio of W), and above ``1e-6 s_1``, the
       resolution of the Gram-matrix route, which decides for noise-free data where the
       median is a rounding error. The median of the spectrum estimates the noise level
       because noise spreads over all ``min(2F, P)`` directions while the shape occupies
       only 3K of them; an energy fraction of the whole spectrum (e.g. 99.9 %) would
       instead grow with the noise and push K to its upper bound. Components below the
       noise are dropped: they cannot be estimated and would only make the intersection
       problem worse conditioned.
    2. *Bases.* ``K = ceil(r / 3)``: a basis whose three singular values are only partly
       above the noise is kept, since it still deforms the object.
    3. *Bounds.* ``1 <= K <= max_bases``, at most what the number of frames supports
       (:func:`min_frames_for_bases`), and ``3K <= P - 1`` (centred columns sum to zero).

    On noise-free data with K bases the rule returns K exactly; with Gaussian noise it
    returns K, or fewer when a weak basis sinks entirely below the noise (see the tests).

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Row-centred measurements (any scale).
    max_bases : int, default=10
        Upper bound on K.

    Returns
    -------
    int
        The number of shape bases K.

    Raises
    ------
    MeasurementError
        If W is not a finite (2F, P) array with at least 3 frames.
    ValueError
        If ``max_bases`` is not a positive integer.
    """
    if isinstance(max_bases, bool) or not isinstance(max_bases, (int, np.integer)):
        raise ValueError(f"max_bases must be a positive integer, got {max_bases!r}")
    if max_bases < 1:
        raise ValueError(f"max_bases must be a positive integer, got {max_bases!r}")
    W = check_measurements(W)
    if singular is None:
        singular = spectrum(W).singular
    return _n_bases_from_spectrum(singular, W.shape, int(max_bases))
