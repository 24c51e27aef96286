"""Rotations with orthonormal rows: projection onto them and refinement on SO(3).

:func:`project_to_stiefel` is the nearest matrix with orthonormal rows (the orthogonal polar
factor), used wherever an estimate of a rotation or of an orthogonal transform is rounded to
one. :func:`fit_rotations_to_shapes` refines camera rotations so that given 3D shapes project
onto the tracks, by Gauss-Newton steps on ``R_f exp(skew(w_f))``; :func:`exp_so3` and
:data:`GENERATORS` are the parametrisation it shares with the joint fit of the corrective
triples (:mod:`moju_core.cameras.triples`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["GENERATORS", "exp_so3", "fit_rotations_to_shapes", "project_to_stiefel", "skew"]


def project_to_stiefel(M: np.ndarray) -> np.ndarray:
    """Nearest matrices with orthonormal rows, for a stack of matrices.

    For ``M = U diag(s) V^T`` (thin SVD) the closest matrix with orthonormal rows in the
    Frobenius norm is ``U V^T`` (the orthogonal polar factor). A positive per-matrix scale
    is therefore divided out; a negative one is not (``-R`` has orthonormal rows too). For a
    square cross-covariance ``M = A^T B`` this is the orthogonal ``Q`` minimising
    ``||A Q - B||_F`` (orthogonal Procrustes, reflections allowed).

    Parameters
    ----------
    M : ndarray of shape (..., m, n) with m <= n
        Typically (F, 2, 3): scaled and noisy camera rotations.

    Returns
    -------
    ndarray of shape (..., m, n), float64
        Matrices whose rows are orthonormal (to about 1e-15).

    Raises
    ------
    ValueError
        If ``M`` has fewer than two dimensions or more rows than columns per matrix.
    """
    M = np.asarray(M, dtype=np.float64)
    if M.ndim < 2 or M.shape[-2] > M.shape[-1]:
        raise ValueError(
            f"project_to_stiefel needs matrices with at most as many rows as columns, "
            f"got an array of shape {M.shape}"
        )
    U, _, Vt = np.linalg.svd(M, full_matrices=False)
    return U @ Vt


def skew(w: np.ndarray) -> np.ndarray:
    """Cross-product matrices: (..., 3) -> (..., 3, 3) with ``skew(w) x = w x x``."""
    S = np.zeros(w.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -w[..., 2], w[..., 1]
    S[..., 1, 0], S[..., 1, 2] = w[..., 2], -w[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -w[..., 1], w[..., 0]
    return S


# Generators of so(3): GENERATORS[j] = skew(e_j) (a definition, not a setting).
GENERATORS = skew(np.eye(3))


def exp_so3(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rodrigues' exponential and its right Jacobian for a stack of rotation vectors.

    Parameters
    ----------
    w : ndarray of shape (F, 3)
        Rotation vectors (radians).

    Returns
    -------
    rotation : ndarray of shape (F, 3, 3)
        ``exp(skew(w))``.
    right_jacobian : ndarray of shape (F, 3, 3)
        ``J_r(w)`` with ``exp(skew(w + d)) = exp(skew(w)) exp(skew(J_r(w) d))`` to first
        order in d.
    """
    theta = np.linalg.norm(w, axis=-1)[:, None, None]
    S = skew(w)
    S2 = S @ S
    # (1 - cos t) / t^2 and (t - sin t) / t^3 cancel catastrophically for small t (about
    # 8 digits lost at 1e-4 rad); below that their two-term Taylor series are exact to
    # rounding. L-BFGS starts at w = 0, so this branch is always taken once.
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    c = np.where(small, 1.0 / 6.0 - theta**2 / 120.0, (t - np.sin(t)) / t**3)
    identity = np.eye(3)
    return identity + a * S + b * S2, identity - b * S + c * S2


def fit_rotations_to_shapes(
    rotations: np.ndarray, tracks: np.ndarray, shapes: np.ndarray, iterations: int = 5
) -> np.ndarray:
    """Camera rotations that best project given 3D shapes onto the tracks, from a start.

    Minimises ``sum_f ||W_f - R_f S_f||_F^2`` over rotations R_f with orthonormal rows (an
    unbalanced orthogonal Procrustes problem per frame, without a closed form) by
    Gauss-Newton steps on ``R_f exp(skew(w_f))``: with ``M_f = S_f S_f^T`` and
    ``G_f = W_f S_f^T - R_f M_f`` the step solves ``H_f w_f = g_f`` with
    ``H_ab = tr((R_f E_a)^T R_f E_b M_f)`` and ``g_a = <R_f E_a, G_f>`` (E_a the generators of
    so(3)). The cost in the number of points is the two 3 x 3 and 2 x 3 products per frame.
    Used by the ADMM loop to refine approximate rotations (the windowed estimate) with the
    shapes (see :func:`moju_core.loop.admm.run`).

    Parameters
    ----------
    rotations : ndarray of shape (F, 2, 3)
        Starting rotations (orthonormal rows).
    tracks : ndarray of shape (F, 2, P)
        Centred tracks W_f.
    shapes : ndarray of shape (F, 3, P)
        Shapes S_f.
    iterations : int, default 5
        Gauss-Newton steps (each frame's problem has 3 unknowns and converges in a few).

    Returns
    -------
    ndarray of shape (F, 2, 3)
        Rotations with orthonormal rows.
    """
    full = np.concatenate([rotations, np.cross(rotations[:, 0], rotations[:, 1])[:, None]], axis=1)
    moments = np.einsum("fip,fjp->fij", shapes, shapes)  # M_f = S_f S_f^T, (F, 3, 3)
    cross = np.einsum("fip,fjp->fij", tracks, shapes)  # W_f S_f^T, (F, 2, 3)
    for _ in range(iterations):
        R = full[:, :2]
        directions = np.einsum("fij,ajk->faik", R, GENERATORS)  # R_f E_a, (F, 3, 2, 3)
        gradient = cross - R @ moments
        g = np.einsum("faik,fik->fa", directions, gradient)
        H = np.einsum("faik,fkl,fbil->fab", directions, moments, directions)
        H += 1e-12 * np.trace(H, axis1=1, axis2=2)[:, None, None] * np.eye(3)
        step = np.linalg.solve(H, g[:, :, None])[:, :, 0]
        full = full @ exp_so3(step)[0]
    return project_to_stiefel(full[:, :2])
