"""Masked least squares for low-rank models of W: the solves of alternating least squares.

``W ~ left @ right`` fitted on the observed entries only: every point's coefficients
(:func:`solve_points`) and every frame's rows (:func:`solve_frames`) solved exactly, with a
ridge, vectorised over points and frames. The x and y rows of a frame are seen together, so
they share one normal matrix, built from upper triangles of outer products. Used by the
completion (:mod:`moju_core.completion.missing`) and its exact model
(:mod:`moju_core.completion.exact_model`). Nothing F x F or P x P is formed.
"""

from __future__ import annotations

import numpy as np

from moju_core.spectrum import RANK_FLOOR

#: Ridge of the ALS solves, per feature, relative to that feature's sum of squares over all
#: rows. With a negligible ridge (1e-9 of the mean diagonal) the solves of weak components blew
#: up at ranks above the data's (rolling sheet, 10 % dropout: error at the hidden entries 1.4
#: of the tracks' RMS at rank 12); 1e-5 keeps the error at the well-predicted hidden entries
#: (leverage <= 30) at 0.010-0.067 of the RMS on face3, bumps-osc and paper with the combined
#: occlusion (0.001-0.004 under dropout); 1e-3 and above bias the fit (0.04 on an exact
#: rank-4 W).
ALS_RIDGE = 1e-5


def exact_span(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the column space of ``left @ right`` at its exact rank
    (singular values above ``RANK_FLOOR`` of the largest), (2F, r)."""
    q, r = np.linalg.qr(left)
    u, s, _ = np.linalg.svd(r @ right, full_matrices=False)
    return np.ascontiguousarray(q @ u[:, s > RANK_FLOOR * s[0]])


def centred_part(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``left @ right`` (2F, n; uncentred) as ``centred_left @ c + translation``: the row
    means, and a basis (2F, r) of the centred part at its exact rank (singular values above
    ``RANK_FLOOR`` of the largest)."""
    mean = right.mean(axis=1, keepdims=True)
    q, r = np.linalg.qr(left)
    u, s, _ = np.linalg.svd(r @ (right - mean), full_matrices=False)
    keep = s > RANK_FLOOR * s[0]
    return np.ascontiguousarray(q @ (u[:, keep] * s[keep])), (left @ mean)[:, 0]


def solve_points(
    left: np.ndarray, data: np.ndarray, visibility: np.ndarray, ridge: float = ALS_RIDGE
) -> np.ndarray:
    """Every point's coefficients ``argmin_x sum_i (d_ij - left_i x)^2`` over its observed rows
    i of W, with a ridge, as (k, m).

    left (2F, k); data (2F, m), zero where unobserved; visibility (F, m), bool (x and y of a
    frame are seen together); ``ridge`` as in :data:`ALS_RIDGE`. O(F m k^2) for the normal
    matrices (:func:`point_normals`), O(m k^3) for the solves.
    """
    normals = point_normals(left, visibility)
    add_ridge(normals, left, ridge)
    return np.linalg.solve(normals, (data.T @ left)[:, :, None])[:, :, 0].T


def point_normals(left: np.ndarray, visibility: np.ndarray) -> np.ndarray:
    """Each point's ``sum_i left_i left_i^T`` over its observed rows i, (m, k, k).

    left (2F, k); visibility (F, m), bool: rows 2f and 2f + 1 (x and y) are seen together, so
    their outer products are summed once per frame before they are weighted. O(F m k^2).
    """
    n_rows, k = left.shape
    frame_outer = upper_outer(left).reshape(n_rows // 2, 2, -1).sum(axis=1)
    return symmetric(visibility.T.astype(np.float64) @ frame_outer, k)


def solve_frames(
    features: np.ndarray, data: np.ndarray, visibility: np.ndarray, ridge: float = ALS_RIDGE
) -> np.ndarray:
    """Every row's coefficients ``argmin_y sum_j (d_ij - features_j y)^2`` over the points j
    observed in it, with a ridge, as (k, 2F).

    features (m, k), one row per point; data (2F, m), zero where unobserved; visibility
    (F, m), bool. The x and y rows of a frame share their normal matrix: one per frame,
    solved for both. O(F m k^2 + F k^3).
    """
    k = features.shape[1]
    n_frames = visibility.shape[0]
    normals = frame_normals(features, visibility)
    add_ridge(normals, features, ridge)
    rhs = (data @ features).reshape(n_frames, 2, k).transpose(0, 2, 1)  # (F, k, 2): x, y
    return np.linalg.solve(normals, rhs).transpose(1, 0, 2).reshape(k, 2 * n_frames)


def frame_normals(features: np.ndarray, visibility: np.ndarray) -> np.ndarray:
    """Each frame's ``sum_j features_j features_j^T`` over the points j it sees, (F, k, k).

    features (m, k), one row per point; visibility (F, m), bool. O(F m k^2).
    """
    return symmetric(visibility.astype(np.float64) @ upper_outer(features), features.shape[1])


def upper_outer(features: np.ndarray) -> np.ndarray:
    """Each row's outer product ``f_i f_i^T``, upper triangle only, (n, k (k + 1) / 2)."""
    upper, lower = np.triu_indices(features.shape[1])
    return features[:, upper] * features[:, lower]


def symmetric(upper_entries: np.ndarray, k: int) -> np.ndarray:
    """(m, k, k) symmetric matrices from their upper triangles (m, k (k + 1) / 2)."""
    upper, lower = np.triu_indices(k)
    position = np.empty((k, k), dtype=np.intp)  # entry (i, j) -> its place in the triangle
    position[upper, lower] = position[lower, upper] = np.arange(upper.size)
    return np.take(upper_entries, position.ravel(), axis=1).reshape(-1, k, k)


def add_ridge(normals: np.ndarray, features: np.ndarray, ridge: float) -> None:
    """Add to every normal matrix (m, k, k), in place, ``ridge`` times each feature's sum of
    squares over all rows: invariant to the scaling of either factor, and relatively
    stronger for columns seen in few rows."""
    diagonal = np.arange(features.shape[1])
    normals[:, diagonal, diagonal] += ridge * np.einsum("ik,ik->k", features, features) + 1e-300
