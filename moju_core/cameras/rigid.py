"""Camera rotations of a rigid object: Tomasi and Kanade's factorisation with metric upgrade.

``W ~ M B`` at rank 3; the corrective 3 x 3 matrix ``G`` that makes every frame block
``M_f G`` a scaled rotation follows from linear (metric) constraints on ``Q = G G^T``
(:func:`metric_constraints`). Exact for a rigid object, a fast fallback for nearly rigid
ones, and the building block of the windowed estimate (:mod:`moju_core.cameras.windowed`).
It works on the left singular vectors of W only (:func:`moju_core.spectrum.spectrum`).
"""

from __future__ import annotations

import numpy as np

from moju_core.cameras.bases import check_measurements, check_n_bases
from moju_core.cameras.refinement import project_to_stiefel
from moju_core.cameras.symmetric import svec, svec_indices
from moju_core.spectrum import Spectrum, spectrum

__all__ = ["metric_constraints", "rigid_from_factor", "rigid_from_spectrum", "rigid_rotations"]


def metric_constraints(Pi: np.ndarray) -> np.ndarray:
    """Orthonormality constraints on Q for every frame, as rows acting on svec(Q).

    Frame f, with rows ``a = Pi[2f]`` and ``b = Pi[2f + 1]``, requires
    ``a Q a^T - b Q b^T = 0`` and ``a Q b^T = 0`` (equal row norms, orthogonal rows of the
    corrected block). Both are Frobenius products ``<M, Q>`` with the symmetric matrices
    ``a a^T - b b^T`` and ``(a b^T + b a^T) / 2``, hence rows ``svec(M)``.

    Parameters
    ----------
    Pi : ndarray of shape (..., 2F, n)
        One motion factor or a stack of them.

    Returns
    -------
    ndarray of shape (..., 2F, n (n + 1) / 2)
        Rows 2f (equal norms) and 2f + 1 (orthogonality) belong to frame f.
    """
    a, b = Pi[..., 0::2, :], Pi[..., 1::2, :]
    equal_norms = np.einsum("...fi,...fj->...fij", a, a) - np.einsum("...fi,...fj->...fij", b, b)
    orthogonal = np.einsum("...fi,...fj->...fij", a, b)
    orthogonal = 0.5 * (orthogonal + np.swapaxes(orthogonal, -1, -2))
    rows = np.stack([svec(equal_norms), svec(orthogonal)], axis=-2)
    return rows.reshape(*Pi.shape[:-1], rows.shape[-1])


def rigid_from_factor(M: np.ndarray) -> np.ndarray:
    """Metric upgrade of rank-3 motion factors into rotations.

    The corrective Q = G G^T solves the orthonormality constraints of every frame in the
    least-squares sense (see :func:`rigid_rotations`).

    Parameters
    ----------
    M : ndarray of shape (2F, 3) or (B, 2F, 3)
        One motion factor, or a stack of B (e.g. one per window of frames).

    Returns
    -------
    ndarray of shape (F, 2, 3) or (B, F, 2, 3)
    """
    stacked = M if M.ndim == 3 else M[None]
    constraints = metric_constraints(stacked)
    # Homogeneous least squares: Q is the right singular vector of the smallest singular
    # value. No per-frame scale is imposed, so scaled-orthographic data (zoom) work as well.
    _, _, Vt = np.linalg.svd(constraints, full_matrices=False)
    rows, cols, weights = svec_indices(3)
    Q = np.zeros((stacked.shape[0], 3, 3))
    Q[:, rows, cols] = Vt[:, -1] / weights
    Q[:, cols, rows] = Vt[:, -1] / weights
    Q *= np.where(np.trace(Q, axis1=1, axis2=2) < 0.0, -1.0, 1.0)[:, None, None]
    eigenvalues, eigenvectors = np.linalg.eigh(Q)
    # Eigen-clip: noise can make the least-squares Q slightly indefinite.
    G = eigenvectors * np.sqrt(np.clip(eigenvalues, 0.0, None))[:, None, :]
    rotations = project_to_stiefel((stacked @ G).reshape(stacked.shape[0], -1, 2, 3))
    return rotations if M.ndim == 3 else rotations[0]


def rigid_from_spectrum(spectrum: Spectrum) -> np.ndarray:
    """Tomasi-Kanade rotations from the spectrum of W (motion factor ``U_3 S_3^{1/2}``)."""
    return rigid_from_factor(spectrum.left[:, :3] * np.sqrt(spectrum.singular[:3]))


def rigid_rotations(W: np.ndarray) -> np.ndarray:
    """Camera rotations of a rigid object (Tomasi and Kanade, IJCV 1992).

    ``W ~ M B`` at rank 3 (``M = U_3 S_3^{1/2}``); the corrective 3 x 3 matrix G makes every
    frame block ``M_f G`` a scaled rotation. With ``Q = G G^T`` the conditions are linear:
    ``m_2f Q m_2f^T = m_2f+1 Q m_2f+1^T`` and ``m_2f Q m_2f+1^T = 0``; Q spans their
    (least-squares) null space, is clipped to PSD, ``G = V Lambda^{1/2}``, and each
    ``M_f G`` is projected to the nearest matrix with orthonormal rows. The scale of Q is
    free: the projection divides it out, which also admits a per-frame zoom.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Row-centred measurements, F >= 3 and P >= 4.

    Returns
    -------
    ndarray of shape (F, 2, 3), float64
        Rotations with orthonormal rows, up to one global rotation and reflection.

    Raises
    ------
    MeasurementError
        If W has an odd number of rows, non-finite values, fewer than 3 frames or fewer
        than 4 points.
    """
    W = check_measurements(W)
    check_n_bases(1, W.shape[0] // 2, W.shape[1])
    return rigid_from_spectrum(spectrum(W))
