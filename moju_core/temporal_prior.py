"""The temporal smoothness prior on the shapes, and the two ways the loop applies it.

A point on a deforming surface moves smoothly between frames when the video is sampled fast
enough. The prior ``gamma / 2 ||D S||_F^2`` penalises the second differences along the frames
(D is the (F - 2) x F second-difference matrix, ``(D S)_f = S_f - 2 S_{f+1} + S_{f+2}``,
applied to every coordinate of every point): it costs nothing for a point that moves at
constant velocity and lets a frame's unseen depth borrow from the neighbouring frames, which
see that direction in their image plane when the camera turns (the trajectory-space argument
of Akhter et al., NIPS 2008, without a fixed basis). With ``gamma = 0`` the loop is the paper's.

**Fixed cameras: a filter after the S# step.** After the singular value threshold
(Algorithm 1, step 10) the result is passed through the proximal operator of the prior at the
current penalty,

    S# <- G_rho SVT(f(S) - L1 / rho),   G_rho = (I + (gamma / rho) D^T D)^{-1}   (F x F),

a splitting of the step's two terms (each proximal operator in turn). ``G_rho`` acts on the
frames only, so it filters the temporal factor of the thresholded S#: with ``S# = U Sigma V^T``
of rank r the result is ``(G_rho U) Sigma V^T``, for F x F x r operations - nearly free.

**Cameras refined in the loop: the exact S-update.** When the loop also re-fits the rotations
to S# (windowed cameras, :mod:`moju_core.cameras`), the splitting is not enough: measured at
2,000 points with the cloth, e3D 0.115 for every weight from 1 to 100 against 0.04 with the
prior solved exactly. The S-update (step 1) then couples the frames:

    (R^T R + rho I + gamma (D^T D kron I_3)) S = R^T W + rho T

for every point (one 3F x 3F system shared by all columns). Its matrix is
``B - N N^T`` with ``B = ((1 + rho) I_F + gamma D^T D) kron I_3`` (per coordinate, a filter
along the frames) and ``N`` the 3F x F matrix of the viewing directions (``R_f^T R_f = I -
n_f n_f^T``). The Woodbury identity solves it with two F x F filters and one F x F solve per
column block, never forming a 3F x 3F matrix:

    S = Y + G (n * u),   Y = G X,   u = C^{-1} (n . Y),
    G = ((1 + rho) I + gamma D^T D)^{-1},   C_fg = delta_fg - G[f, g] (n_f . n_g)

where ``X`` is the right-hand side, ``n . Y`` is the per-frame dot product with the viewing
direction and ``n * u`` puts ``u_f`` along ``n_f``. ``C`` is positive definite
(``N^T B^{-1} N <= I / (1 + rho)``). It costs about 4 times the plain S-update, which is why
the fixed-camera case uses the filter: with known rotations both give the same e3D to within
2 % on the sheets and face3 (2,000 points, weights 0-1,000).
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
    """The prior ``weight / 2 ||D S#||^2`` for F frames, ready for :func:`smoothing_filter` or
    :func:`smooth_data_step`."""
    if weight < 0 or not np.isfinite(weight):
        raise ValueError(f"the smoothness weight must be a finite number >= 0, got {weight!r}")
    difference = second_differences(n_frames)
    values, vectors = np.linalg.eigh(difference.T @ difference)
    return TemporalPrior(np.clip(values, 0.0, None), vectors, float(weight))


def smoothing_filter(prior: TemporalPrior, rho: float) -> np.ndarray:
    """Proximal operator of the prior at penalty rho, as a matrix on the frames.

    ``argmin_Y gamma/2 ||D Y||^2 + rho/2 ||Y - X||^2 = G X`` with
    ``G = (I + (gamma / rho) D^T D)^{-1} = V diag(1 / (1 + (gamma / rho) lambda)) V^T``.

    Parameters
    ----------
    prior : TemporalPrior
    rho : float
        Penalty, > 0.

    Returns
    -------
    ndarray of shape (F, F)
        Symmetric, eigenvalues in (0, 1]; constant and linear motion pass unchanged.
    """
    gains = 1.0 / (1.0 + (prior.weight / rho) * prior.values)
    return (prior.vectors * gains) @ prior.vectors.T


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
