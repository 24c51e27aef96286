"""Orthographic camera algebra on stacks of per-frame rotations ``R`` of shape (F, 2, 3).

``R = blockdiag(R_1..R_F)`` is never formed: every operation works frame by frame on the stack,
vectorised over points.
"""

from __future__ import annotations

import numpy as np


def project(rotations: np.ndarray, shapes: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Image tracks of shapes: ``W_f = R_f S_f``.

    Parameters
    ----------
    rotations : ndarray of shape (F, 2, 3)
    shapes : ndarray of shape (F, 3, P)
    out : ndarray of shape (F, 2, P), optional
        Where to write the result.

    Returns
    -------
    ndarray of shape (F, 2, P)
    """
    return np.matmul(rotations, shapes, out=out)


def back_project(rotations: np.ndarray, tracks: np.ndarray) -> np.ndarray:
    """``pinv(R) W``: per frame ``R_f^T W_f`` (rows of R_f are orthonormal), zero depth.

    Parameters
    ----------
    rotations : ndarray of shape (F, 2, 3)
    tracks : ndarray of shape (F, 2, P)

    Returns
    -------
    ndarray of shape (F, 3, P)
    """
    return np.einsum("fji,fjp->fip", rotations, tracks)


def viewing_directions(rotations: np.ndarray) -> np.ndarray:
    """Unit viewing direction of every frame, ``n_f = r_1 x r_2`` (the null space of R_f).

    Returns
    -------
    ndarray of shape (F, 3)
    """
    normals = np.cross(rotations[:, 0], rotations[:, 1])
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def data_step(
    back_projected: np.ndarray,
    normals: np.ndarray,
    target: np.ndarray,
    rho: float,
    out: np.ndarray | None = None,
    observed: np.ndarray | None = None,
) -> np.ndarray:
    """S-update (Algorithm 1, step 1): solve ``(R^T R + rho I) S = R^T W + rho T`` per frame.

    ``R_f^T R_f = I - n_f n_f^T`` is the projector onto the image plane of frame f, so the
    3 x 3 system has the closed form ``S_f = (R_f^T W_f + rho T_f + n_f n_f^T T_f) / (1 + rho)``:
    the in-plane part averages the measurements with the target, the depth part is the
    target's.

    Parameters
    ----------
    back_projected : ndarray of shape (F, 3, P)
        ``R_f^T W_f`` (see :func:`back_project`).
    normals : ndarray of shape (F, 3)
        Viewing directions (see :func:`viewing_directions`).
    target : ndarray of shape (F, 3, P)
        ``finv(S# + L1 / rho)``.
    rho : float
        Penalty parameter, > 0.
    out : ndarray of shape (F, 3, P), optional
        Where to write the result (must not share memory with the inputs).
    observed : ndarray of shape (F, P), bool, optional
        Where the points are observed. An unobserved entry has no data term, so its solution
        is the target itself (``rho S_f = rho T_f``); None means all are observed.

    Returns
    -------
    ndarray of shape (F, 3, P)
    """
    # (rho I + n_f n_f^T) T_f as one batched 3 x 3 product per frame.
    coupling = np.einsum("fi,fj->fij", normals, normals)
    coupling += rho * np.eye(3)
    out = np.matmul(coupling, target, out=out)
    out += back_projected
    out *= 1.0 / (1.0 + rho)
    if observed is not None:
        np.copyto(out, target, where=~observed[:, None, :])
    return out


def fill_unobserved(
    rotations: np.ndarray, tracks: np.ndarray, shapes: np.ndarray, observed: np.ndarray
) -> np.ndarray:
    """Tracks with every unobserved entry replaced by the projection of the current shape.

    A data term over the observed entries, ``sum_{observed} ||W_fj - R_f S_fj||^2``, is
    majorised at the current S by the complete term of these filled tracks (equal at S,
    larger elsewhere): steps that need complete tracks (the exact temporal-prior S-update,
    the rotation refinement) take them and still decrease the masked objective.

    Parameters
    ----------
    rotations : ndarray of shape (F, 2, 3)
    tracks : ndarray of shape (F, 2, P)
    shapes : ndarray of shape (F, 3, P)
    observed : ndarray of shape (F, P), bool

    Returns
    -------
    ndarray of shape (F, 2, P)
    """
    return np.where(observed[:, None, :], tracks, project(rotations, shapes))
