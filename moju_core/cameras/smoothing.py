"""Given camera rotations as measurements of a smooth path: frame-to-frame jitter removed.

A video's camera moves smoothly, so rotations that come with the tracks (from a calibration, a
SLAM system or another estimator) are a smooth path plus, often, an independent error per
frame. The solver needs consistency from frame to frame more than absolute accuracy: an
independent 1-degree error per frame makes the world-frame shapes jitter by a rotation per
frame, which the low-rank model cannot hold (e3D 1.4-2 times that of the true rotations on the
sheets under an oscillating camera, 15 times on a face), while a smooth error of a few degrees
costs nothing.

:func:`smooth_rotations` fits the six entries of every ``R_f`` (2 x 3) with a Whittaker
smoother (penalised second differences in time), diagonalised by the DCT, and chooses the
weight by generalised cross-validation (GCV) over a logarithmic grid; the result is projected
back onto rotations. The rotations are returned unchanged, bit for bit, when GCV's best weight
is the smallest of the grid (no jitter to remove: true, smooth paths, fast turns included), and
when von Neumann's ratio test does not find them ordered in time (:func:`is_ordered_path`):
an unordered set of views is not a path with small errors, and "smoothing" it would move the
views by tens of degrees. Cost ``O(F log F)`` per weight, ``O(F)`` memory.
"""

from __future__ import annotations

import numpy as np
from scipy.fft import dct, idct

from moju_core.cameras.refinement import project_to_stiefel

__all__ = ["ORDER_TEST_Z", "SMOOTHING_WEIGHTS", "is_ordered_path", "smooth_rotations"]

#: GCV's search grid of the Whittaker weight (entries of rotations are in [-1, 1]). At the
#: smallest weight the filter passes the highest frequency to within 2e-3 (no smoothing); at
#: the largest it leaves a straight line over hundreds of frames. Eight steps per decade.
SMOOTHING_WEIGHTS = np.logspace(-4.0, 8.0, 97)
#: One-sided 1 % level of von Neumann's ratio test (the standard normal's 99th percentile):
#: views in no particular order are taken for a path, and smoothed, once in a hundred at most.
ORDER_TEST_Z = 2.326


def is_ordered_path(entries: np.ndarray) -> bool:
    """Whether rows (F, C) in frame order are a path rather than independent draws.

    Von Neumann's ratio test of serial independence: the mean squared successive difference
    over the variance is 2 in expectation for independent rows, with a standard deviation of
    ``2 sqrt((F - 2) / (F^2 - 1))``; a smooth path (plus small errors) gives much less. The
    rows count as a path when the ratio is below 2 by more than :data:`ORDER_TEST_Z` standard
    deviations. O(F C).
    """
    n_frames = entries.shape[0]
    spread = float(np.sum((entries - entries.mean(axis=0)) ** 2)) / n_frames
    if spread == 0.0:
        return False
    steps = float(np.sum(np.diff(entries, axis=0) ** 2)) / (n_frames - 1)
    deviation = 2.0 * np.sqrt((n_frames - 2) / (n_frames**2 - 1))
    return steps / spread < 2.0 - ORDER_TEST_Z * deviation


def smooth_rotations(rotations: np.ndarray) -> tuple[np.ndarray, float]:
    """The rotations with the jitter that GCV finds in them removed.

    Parameters
    ----------
    rotations : ndarray of shape (F, 2, 3)
        Camera rotations (orthonormal rows), in frame order.

    Returns
    -------
    smoothed : ndarray of shape (F, 2, 3)
        Rotations with orthonormal rows; ``rotations`` itself when no smoothing is chosen.
    weight : float
        The Whittaker weight GCV chose; 0.0 when the rotations are returned unchanged.
    """
    n_frames = rotations.shape[0]
    if n_frames < 4:
        return rotations, 0.0
    entries = rotations.reshape(n_frames, 6)
    coefficients = dct(entries, axis=0, norm="ortho")
    # Eigenvalues of D2^T D2 (second differences, reflecting ends) in the DCT-II basis.
    penalty = (2.0 - 2.0 * np.cos(np.pi * np.arange(n_frames) / n_frames)) ** 2
    gains = 1.0 / (1.0 + SMOOTHING_WEIGHTS[:, None] * penalty[None, :])  # (weights, F)
    residual = np.einsum("wf,fc->w", (1.0 - gains) ** 2, coefficients**2)
    gcv = n_frames * residual / (n_frames - gains.sum(axis=1)) ** 2
    best = int(np.argmin(gcv))
    if best == 0 or not is_ordered_path(entries):
        return rotations, 0.0
    smoothed = idct(gains[best][:, None] * coefficients, axis=0, norm="ortho")
    return project_to_stiefel(smoothed.reshape(n_frames, 2, 3)), float(SMOOTHING_WEIGHTS[best])
