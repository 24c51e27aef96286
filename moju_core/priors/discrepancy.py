"""The nuclear-norm weight of noisy tracks by the discrepancy principle (Morozov).

With the soft data term the loop solves ``1/2 sum_f ||W_f - R_f S_f||^2 + beta2 ||S#||_*``.
A weight too small lets the shapes absorb the tracks' noise as deformation: the residual then
holds far less than the noise's energy (markers on an articulated body at 5.5 % noise: 1 % of
it, e3D 1.5-2 times that of a plain nuclear-norm solve at its best weight). The discrepancy
principle asks the residual to hold the noise: ``||W - R S||^2 ~ sigma^2 n`` over the ``n``
fitted entries, with ``sigma^2`` the noise variance the spectrum of the tracks gives
(:func:`moju_core.spectrum.noise_variance`).

:func:`discrepancy` measures that ratio after a solve, ``O(F P)``. When it is below
:data:`ABSORBED` (the fit explained more of the noise than it left), the solver solves again
with the weight :func:`next_weight` predicts: the residual of singular value thresholding
grows as the square of its threshold where the thresholded values are noise, so the weight is
scaled by ``sqrt(1 / discrepancy)``, at most :data:`RESOLVES` times.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ABSORBED", "RESOLVES", "discrepancy", "next_weight"]

#: Below this ratio of residual to noise energy the fit has absorbed most of the noise.
ABSORBED = 0.5
#: Solves with a corrected weight at most (each a full loop).
RESOLVES = 3


def discrepancy(
    tracks: np.ndarray, rotations: np.ndarray, shapes: np.ndarray, noise: float
) -> float:
    """Residual energy of a soft fit over the energy the noise alone would leave.

    Parameters
    ----------
    tracks : ndarray of shape (F, 2, P)
        Centred, scale-normalised tracks (every entry observed).
    rotations : ndarray of shape (F, 2, 3)
    shapes : ndarray of shape (F, 3, P)
        The loop's shapes, same units as ``tracks``.
    noise : float
        Noise variance per entry of ``tracks`` (> 0).

    Returns
    -------
    float
        ``||W - R S||^2 / (noise * 2 F P)``, each frame's mean residual (the translation)
        removed first; 1 when the residual holds exactly the noise.
    """
    residual = np.einsum("fij,fjp->fip", rotations, shapes) - tracks
    residual -= residual.mean(axis=2, keepdims=True)
    return float(np.sum(residual**2) / (noise * residual.size))


def next_weight(beta2: float, ratio: float) -> float:
    """The weight that should bring the discrepancy ``ratio`` to 1: ``beta2 / sqrt(ratio)``,
    at most 16 times larger (a ratio of 0 would otherwise give an infinite weight)."""
    return beta2 * min(16.0, 1.0 / np.sqrt(max(ratio, 1e-300)))
