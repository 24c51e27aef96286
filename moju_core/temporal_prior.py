"""The temporal smoothness prior on 3D trajectories and the S-update it leads to.

A point on a deforming surface moves smoothly between frames when the video is sampled fast
enough. The prior ``gamma / 2 ||D S||_F^2`` penalises the second differences along the frames
of every 3D trajectory (D is the (F - 2) x F second-difference matrix, applied to each
coordinate of each point: ``(D S)_f = S_f - 2 S_{f+1} + S_{f+2}``). It adds nothing for a
trajectory that moves at constant velocity and lets a frame's unseen depth borrow from the
neighbouring frames, which see that direction in their image plane when the camera turns: the
trajectory-space argument of Akhter et al. (NIPS 2008) without a fixed basis. With
``gamma = 0`` the loop is the paper's.

With the prior the S-update of Algorithm 1 (step 1) couples the frames:

    (R^T R + rho I + gamma (D^T D kron I_3)) S = R^T W + rho T

for every point (one 3F x 3F system shared by all columns). Its matrix is
``B - N N^T`` with ``B = ((1 + rho) I_F + gamma D^T D) kron I_3`` (per coordinate, a filter
along the frames) and ``N`` the 3F x F matrix of the viewing directions (``R_f^T R_f = I -
n_f n_f^T``). The Woodbury identity solves it with two F x F filters and one F x F solve per
column block, never forming a 3F x 3F matrix:

    S = Y + G_rho (n * u),   Y = G_rho X,   u = C^{-1} (n . Y),
    G_rho = ((1 + rho) I + gamma D^T D)^{-1},   C_fg = delta_fg - G_rho[f, g] (n_f . n_g)

where ``X`` is the right-hand side, ``n . Y`` is the per-frame dot product with the viewing
direction and ``n * u`` puts ``u_f`` along ``n_f``. ``C`` is positive definite
(``N^T B^{-1} N <= I / (1 + rho)``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class TemporalPrior(NamedTuple):
    """Eigendecomposition ``D^T D = V diag(values) V^T`` of the second-difference penalty.

    values : ndarray of shape (F,), >= 0 (two zeros: constant and linear motion are free).
    vectors : ndarray of shape (F, F), orthonormal columns.
    weight : float
        gamma, the weight of the prior relative to the data term (scale-normalised tracks).
    """

    values: np.ndarray
    vectors: np.ndarray
    weight: float


def second_differences(n_frames: int) -> np.ndarray:
    """The second-difference matrix D along the frames, shape (max(F - 2, 0), F).

    Row f is ``e_f - 2 e_{f+1} + e_{f+2}``; with fewer than three frames it has no rows (no
    acceleration to penalise).
    """
    return np.diff(np.eye(n_frames), n=2, axis=0)


def temporal_prior(n_frames: int, weight: float) -> TemporalPrior:
    """The prior ``weight / 2 ||D S||^2`` for F frames, ready for :func:`smooth_data_step`."""
    if weight < 0 or not np.isfinite(weight):
        raise ValueError(f"the smoothness weight must be a finite number >= 0, got {weight!r}")
    difference = second_differences(n_frames)
    values, vectors = np.linalg.eigh(difference.T @ difference)
    return TemporalPrior(np.clip(values, 0.0, None), vectors, float(weight))


def filter_matrix(prior: TemporalPrior, rho: float) -> np.ndarray:
    """``G_rho = ((1 + rho) I + gamma D^T D)^{-1}`` (F x F, symmetric positive definite)."""
    return (prior.vectors / (1.0 + rho + prior.weight * prior.values)) @ prior.vectors.T


def smooth_data_step(
    back_projected: np.ndarray,
    normals: np.ndarray,
    target: np.ndarray,
    rho: float,
    prior: TemporalPrior,
    out: np.ndarray,
) -> np.ndarray:
    """S-update with the temporal prior (see the module docstring for the formulas).

    Solves ``(R^T R + rho I + gamma D^T D kron I_3) S = R^T W + rho T`` for every point.

    Parameters
    ----------
    back_projected : ndarray of shape (F, 3, P)
        ``R_f^T W_f`` (:func:`moju_core.camera.back_project`).
    normals : ndarray of shape (F, 3)
        Unit viewing directions (:func:`moju_core.camera.viewing_directions`).
    target : ndarray of shape (F, 3, P), C-contiguous
        ``finv(S# + L1 / rho)``. It is used as scratch space and overwritten.
    rho : float
        Penalty parameter, > 0.
    prior : TemporalPrior
        The second-difference penalty and its weight (:func:`temporal_prior`).
    out : ndarray of shape (F, 3, P), C-contiguous
        Where the solution is written (must not share memory with the inputs).

    Returns
    -------
    ndarray of shape (F, 3, P)
        ``out``.
    """
    n_frames, _, n_points = out.shape
    smoother = filter_matrix(prior, rho)
    capacitance = np.eye(n_frames) - smoother * (normals @ normals.T)
    # G diag(n_c) C^{-1} for each coordinate c: the correction G (n * u) with u = C^{-1} z is
    # then three (F, F) x (F, P) products (a solve with P right-hand sides costs as much as
    # all three).
    corrections = [(smoother * normals[:, c]) @ np.linalg.inv(capacitance) for c in range(3)]
    # Right-hand side X = R^T W + rho T, then Y = G X (a filter along the frames of every
    # coordinate of every point: one (F, F) x (F, 3P) product).
    np.multiply(target, rho, out=out)
    out += back_projected
    filtered = np.matmul(smoother, out.reshape(n_frames, -1), out=target.reshape(n_frames, -1))
    filtered = filtered.reshape(n_frames, 3, n_points)
    along_view = filtered[:, 0, :] * normals[:, 0, None]  # z = n . Y, (F, P)
    along_view += filtered[:, 1, :] * normals[:, 1, None]
    along_view += filtered[:, 2, :] * normals[:, 2, None]
    for c in range(3):
        np.matmul(corrections[c], along_view, out=out[:, c, :])
        out[:, c, :] += filtered[:, c, :]
    return out
