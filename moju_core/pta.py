"""Point trajectory approach (PTA): Akhter, Sheikh, Khan and Kanade, "Nonrigid Structure from
Motion in Trajectory Space", NIPS 2008 / TPAMI 2011; a baseline of the paper's Table 1.

Every point's 3D trajectory is a combination of the first k vectors of the DCT-II basis over
the F frames, the same basis for every point and every coordinate:

    S_f = sum_k theta_k(f) A_k        (S_f: 3 x P shape of frame f, A_k: 3 x P coefficients)

so, in trajectory form, ``S = (Theta kron I_3) A`` with ``Theta`` (F x k) the basis and ``A``
(3k x P). The image of frame f is ``W_f = R_f S_f = [theta_1(f) R_f, ..., theta_k(f) R_f] A``:
with the camera rotations given, one linear system ``W = M A`` with ``M`` of shape (2F x 3k)
is shared by all P points. It is solved once, in the least-squares sense, for all columns at
once; nothing P x P is formed. The solve is exact when the trajectories lie in the span of the
basis and M has full column rank; M needs ``3k <= 2F`` and loses rank when the camera's own
motion is itself well described by the first k cosines (the method's known weakness, Akhter et
al. Sec. 4): then the part of the shape that moves like the camera cannot be told apart from
the camera motion.

The rotations are the solver's (known, or estimated by the intersection or rigid method);
Akhter et al. estimate them with a trajectory-constrained factorisation of their own, which is
not reproduced here.
"""

from __future__ import annotations

import warnings

import numpy as np

#: Relative singular-value cut-off of the least-squares solve: directions of M weaker than this
#: (times its largest singular value) are treated as missing.
RCOND = 1e-10
#: Ridge of the per-point solves with missing data, relative to M's largest singular value: a
#: point seen in few frames has fewer equations than coefficients.
MASKED_RIDGE = 1e-2

#: Condition number of M above which the solve warns: errors in the tracks can then grow more
#: than ten-thousandfold in the shapes (e.g. estimated rotations that hardly change).
WARN_CONDITION = 1e4


def dct_basis(n_frames: int, n_bases: int) -> np.ndarray:
    """First ``n_bases`` vectors of the orthonormal DCT-II basis over ``n_frames`` samples.

    ``theta_k(f) = sqrt(c_k / F) cos(pi (2f + 1) k / (2F))`` with ``c_0 = 1`` and ``c_k = 2``
    for ``k >= 1``; ``theta_0`` is constant (the mean shape), the others oscillate with
    ``k / 2`` cycles over the sequence.

    Parameters
    ----------
    n_frames : int
        Number of frames F, >= 1.
    n_bases : int
        Number of basis vectors k, ``1 <= k <= F``.

    Returns
    -------
    ndarray of shape (F, k), float64
        Orthonormal columns.
    """
    if not 1 <= n_bases <= n_frames:
        raise ValueError(
            f"n_bases must be between 1 and the number of frames {n_frames}, got {n_bases}"
        )
    frames = np.arange(n_frames)[:, None]
    orders = np.arange(n_bases)[None, :]
    basis = np.cos(np.pi * (2 * frames + 1) * orders / (2 * n_frames))
    basis *= np.sqrt(2.0 / n_frames)
    basis[:, 0] = np.sqrt(1.0 / n_frames)
    return basis


def trajectory_system(rotations: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """The matrix ``M = R (Theta kron I_3)`` mapping trajectory coefficients to image tracks.

    Parameters
    ----------
    rotations : ndarray of shape (F, 2, 3)
        Camera rotations.
    basis : ndarray of shape (F, k)
        Trajectory basis ``Theta`` (:func:`dct_basis`).

    Returns
    -------
    ndarray of shape (2F, 3k)
        Rows ``2f, 2f + 1`` are ``[theta_1(f) R_f, ..., theta_k(f) R_f]``; column ``3 k + c``
        multiplies coordinate c of the coefficient shape ``A_k``.
    """
    n_frames, n_bases = basis.shape
    blocks = basis[:, None, :, None] * rotations[:, :, None, :]  # (F, 2, k, 3)
    return blocks.reshape(2 * n_frames, 3 * n_bases)


def solve(
    tracks: np.ndarray,
    rotations: np.ndarray,
    n_bases: int,
    observed: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, float]]:
    """Least-squares trajectory coefficients of all points and the shapes they give.

    ``A = argmin ||W - M A||_F`` (minimum norm when M is rank deficient), then
    ``S_f = sum_k theta_k(f) A_k``.

    Parameters
    ----------
    tracks : ndarray of shape (F, 2, P)
        Centred measurements (``W`` per frame), any scale.
    rotations : ndarray of shape (F, 2, 3)
        Camera rotations (rows orthonormal).
    n_bases : int
        Size k of the trajectory basis, ``3k <= 2F``.
    observed : ndarray of shape (F, P), bool, optional
        Where the points are observed: each point's least-squares problem then uses its
        observed rows only (:func:`_solve_masked`). None: all observed.

    Returns
    -------
    shapes : ndarray of shape (F, 3, P)
        Per-frame shapes in the units of ``tracks``.
    diagnostics : dict of str to float
        ``rank`` (numerical rank of M, at most 3k) and ``condition`` (ratio of M's largest to
        smallest singular value; ``inf`` when rank deficient).

    Warns
    -----
    RuntimeWarning
        When M is rank deficient: the camera motion is too close to the trajectory basis and
        part of the shape is undetermined (set to its minimum-norm value).
    """
    n_frames, _, n_points = tracks.shape
    if not 1 <= 3 * n_bases <= 2 * n_frames:
        raise ValueError(
            f"the trajectory basis needs 3k <= 2F unknowns per point: k={n_bases} is too "
            f"large for F={n_frames} frames (at most {2 * n_frames // 3})"
        )
    basis = dct_basis(n_frames, n_bases)
    system = trajectory_system(rotations, basis)
    # Pseudo-inverse of the small (2F, 3k) matrix through its SVD, applied to all P columns
    # at once: one (3k, 2F) x (2F, P) product.
    u, s, vt = np.linalg.svd(system, full_matrices=False)
    rank = int(np.count_nonzero(s > RCOND * s[0]))
    condition = float(s[0] / s[-1]) if rank == 3 * n_bases else float("inf")
    if condition > WARN_CONDITION:
        warnings.warn(
            f"the camera motion is too close to the first {n_bases} trajectory bases: the "
            f"PTA system has rank {rank} of {3 * n_bases} and condition {condition:.3g}, so "
            "part of the shape is undetermined or dominated by noise; lower trajectory_bases "
            "or check the rotations",
            RuntimeWarning,
            stacklevel=2,
        )
    if observed is None:
        pseudo_inverse = (vt[:rank].T / s[:rank]) @ u[:, :rank].T
        coefficients = pseudo_inverse @ tracks.reshape(2 * n_frames, n_points)  # A, (3k, P)
    else:
        coefficients = _solve_masked(system, tracks, observed, s[0])
    shapes = basis @ coefficients.reshape(n_bases, 3 * n_points)  # (F, 3P): row f is S_f
    diagnostics = {"rank": float(rank), "condition": condition}
    return shapes.reshape(n_frames, 3, n_points), diagnostics


def _solve_masked(
    system: np.ndarray, tracks: np.ndarray, observed: np.ndarray, largest: float
) -> np.ndarray:
    """Per-point least squares over the observed rows: ``M_j^T M_j a_j = M_j^T w_j``.

    ``M_j^T M_j = sum_f m_fj M_f^T M_f`` from the frames' 2-row blocks ``M_f`` of the
    (2F, 3k) system, so all P normal matrices (3k x 3k) cost O(F P k^2) and are solved at
    once; a ridge of ``(MASKED_RIDGE sigma_1(M))^2`` keeps the coefficients that a point's
    visible frames leave undetermined near zero instead of failing.

    Returns
    -------
    ndarray of shape (3k, P)
    """
    n_frames, _, n_points = tracks.shape
    size = system.shape[1]
    blocks = system.reshape(n_frames, 2, size)
    frame_normals = np.einsum("fia,fib->fab", blocks, blocks)  # (F, 3k, 3k)
    weights = observed.astype(np.float64)
    normals = np.einsum("fp,fab->pab", weights, frame_normals)
    normals += (MASKED_RIDGE * largest) ** 2 * np.eye(size)
    masked = tracks * weights[:, None, :]
    rhs = np.einsum("fia,fip->pa", blocks, masked)  # (P, 3k)
    return np.linalg.solve(normals, rhs[:, :, None])[:, :, 0].T
