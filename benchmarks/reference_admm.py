"""The "plain ADMM" peer of the speed benchmark: nuclear-norm NRSfM with known rotations.

A minimal reference written for the benchmarks (not part of ``moju_core``), the kind of solver
a user would write from Dai et al.'s convex formulation:

    min_S  beta ||S#||_* + 1/2 ||R S - W||_F^2,

solved by ADMM on the split ``Z = S#`` with a **fixed** penalty rho and a **fixed** number of
iterations (300 by default), no continuation, no stopping rule:

1. S-update, per frame in closed form: ``(R_f^T R_f + rho I) S_f = R_f^T W_f + rho T_f`` with
   ``T = Z - Y / rho``; as ``R_f^T R_f = I - n_f n_f^T`` (``n_f`` the viewing direction),
   ``S_f = (R_f^T W_f + rho T_f + n_f n_f^T T_f) / (1 + rho)``;
2. Z-update: singular value thresholding of ``S# + Y / rho`` at ``beta / rho``, by a full
   ``np.linalg.svd`` (``full_matrices=False``) of the F x 3P matrix;
3. multiplier update ``Y += rho (S# - Z)``.

``S#`` is F x 3P, row f holding the x, y and z coordinates of all points of frame f (the
mean shape is inside the nuclear norm, as in Dai et al.). The tracks are centred per row and
divided by their RMS first, so ``beta`` and ``rho`` are scale free; ``beta`` is set relative
to the top singular value of the zero-depth start ``(R^T W)#``. Each iteration costs one SVD of
the F x 3P matrix, O(F P min(F, 3P)), plus O(F P) for the rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Iterations of the reference (fixed: the peer does not test convergence).
N_ITER = 300
#: ``beta`` relative to the top singular value of the zero-depth start, and the fixed penalty
#: (on the scale-normalised data). Chosen on face3 and face4 (99 x 500, known rotations) among
#: beta 2e-3 / 1e-2 / 5e-2 and rho 0.1 / 1 / 10: this pair is the most accurate (e3D 0.013 and
#: 0.027) and reaches max |S# - Z| ~ 1e-10 within the 300 iterations; larger rho leaves the
#: depth unresolved (e3D 0.19 at rho 10), larger beta biases the shapes (0.09 at 5e-2).
BETA_RELATIVE = 2e-3
RHO = 0.1


@dataclass
class AdmmResult:
    """Output of :func:`plain_admm`.

    Attributes
    ----------
    shapes : ndarray of shape (F, P, 3), float64
        Reconstructed shapes in the units of the input tracks, each frame centred.
    n_iter : int
        Iterations run.
    gap : float
        ``max |S# - Z|`` after the last iteration (scale-normalised units).
    """

    shapes: np.ndarray
    n_iter: int
    gap: float


def svt(matrix: np.ndarray, threshold: float) -> np.ndarray:
    """Singular value thresholding by a full SVD: ``U max(s - threshold, 0) V^T``.

    Parameters
    ----------
    matrix : ndarray of shape (m, n)
    threshold : float, >= 0

    Returns
    -------
    ndarray of shape (m, n)
    """
    u, s, vt = np.linalg.svd(matrix, full_matrices=False)
    s = np.maximum(s - threshold, 0.0)
    keep = s > 0
    return (u[:, keep] * s[keep]) @ vt[keep]


def plain_admm(
    W: np.ndarray,
    rotations: np.ndarray,
    *,
    n_iter: int = N_ITER,
    beta_relative: float = BETA_RELATIVE,
    rho: float = RHO,
) -> AdmmResult:
    """Nuclear-norm NRSfM with known rotations by plain ADMM (see the module docstring).

    Parameters
    ----------
    W : ndarray of shape (2F, P), float64
        Image tracks; rows 2f and 2f + 1 are x and y of frame f.
    rotations : ndarray of shape (F, 2, 3), float64
        Camera rotations (orthonormal rows).
    n_iter : int, default 300
        Iterations (fixed).
    beta_relative : float, default 2e-3
        ``beta`` over the top singular value of ``(R^T W)#``.
    rho : float, default 0.1
        The fixed penalty.

    Returns
    -------
    AdmmResult
    """
    n_frames, n_points = rotations.shape[0], W.shape[1]
    centred = W - W.mean(axis=1, keepdims=True)
    scale = float(np.sqrt(np.mean(centred**2))) or 1.0
    tracks = (centred / scale).reshape(n_frames, 2, n_points)
    back = np.einsum("fji,fjp->fip", rotations, tracks)  # R_f^T W_f: (F, 3, P)
    normals = np.cross(rotations[:, 0], rotations[:, 1])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    coupling = np.einsum("fi,fj->fij", normals, normals) + rho * np.eye(3)  # rho I + n n^T
    sharp_shape = (n_frames, 3 * n_points)
    beta = beta_relative * float(np.linalg.norm(back.reshape(sharp_shape), 2))
    shapes = back.copy()
    low_rank = back.reshape(sharp_shape).copy()
    multiplier = np.zeros(sharp_shape)
    for _ in range(n_iter):
        target = (low_rank - multiplier / rho).reshape(n_frames, 3, n_points)
        shapes = (np.matmul(coupling, target) + back) / (1.0 + rho)
        sharp = shapes.reshape(sharp_shape)
        low_rank = svt(sharp + multiplier / rho, beta / rho)
        multiplier += rho * (sharp - low_rank)
    gap = float(np.abs(shapes.reshape(sharp_shape) - low_rank).max())
    out = scale * shapes.transpose(0, 2, 1)
    out -= out.mean(axis=1, keepdims=True)
    return AdmmResult(shapes=out, n_iter=n_iter, gap=gap)
