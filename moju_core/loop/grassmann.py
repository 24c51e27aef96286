"""Grassmann points of trajectory groups and the geometry between them.

A local group of trajectories ``S_i`` (3F x n_i, columns are 3D trajectories) is represented by
the span of its top-p left singular vectors ``Phi_i`` (3F x p, orthonormal columns), a point on
the Grassmann manifold G(p, 3F) (paper Eq. 12, ``f_g``). The projection embedding
``Phi -> Phi Phi^T`` gives the projection metric (paper Definition 2)::

    d_g^2(Phi_i, Phi_j) = 0.5 ||Phi_i Phi_i^T - Phi_j Phi_j^T||_F^2 = p - ||Phi_i^T Phi_j||_F^2

Groups are stored contiguously: the columns of a group are ``S[:, bounds[i]:bounds[i + 1]]``
(the solver keeps its arrays permuted into group order; that permutation plays the role of the
paper's ordering vector).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg


def top_subspace(block: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """Top-p left singular vectors and values of one group, through its smaller Gram matrix.

    Parameters
    ----------
    block : ndarray of shape (n, m)
        The group's columns (n = 3F trajectory length, m = group size).
    p : int
        Subspace dimension; at most ``min(n, m)``.

    Returns
    -------
    basis : ndarray of shape (n, p)
        Orthonormal columns spanning the top-p left singular subspace.
    singular_values : ndarray of shape (p,)
        Matching singular values, descending.

    Notes
    -----
    The Gram route squares the condition number, so singular values below about
    ``sqrt(eps) * s_max`` are inaccurate; only the top p (the well-separated ones) are used,
    and the basis is re-orthonormalised by a QR step to remove the rounding the route adds.
    """
    n, m = block.shape
    if m <= n:
        gram = block.T @ block
        values, vectors = scipy.linalg.eigh(gram, subset_by_index=[m - p, m - 1])
        values = np.sqrt(np.clip(values[::-1], 0.0, None))
        basis = block @ vectors[:, ::-1]
    else:
        gram = block @ block.T
        values, vectors = scipy.linalg.eigh(gram, subset_by_index=[n - p, n - 1])
        values = np.sqrt(np.clip(values[::-1], 0.0, None))
        basis = vectors[:, ::-1]
    basis, _ = np.linalg.qr(basis)
    return basis, values


def refine_subspace(block: np.ndarray, previous: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One warm-started subspace-iteration step towards the top-p left singular subspace.

    ``Y = block block^T previous`` followed by QR and a Rayleigh-Ritz step on ``Q^T block``.
    Inside the ADMM loop S changes little between iterations, so one step from the previous
    basis tracks the exact subspace at a cost of ``O(n m p)`` instead of the ``O(min(n,m)^3)``
    eigendecomposition (repeated calls on a fixed block converge to :func:`top_subspace`).

    Parameters
    ----------
    block : ndarray of shape (n, m)
    previous : ndarray of shape (n, p)
        The basis from the previous iteration (orthonormal columns).

    Returns
    -------
    basis : ndarray of shape (n, p)
    singular_values : ndarray of shape (p,)
        Ritz estimates of the top-p singular values, descending.
    """
    power = block @ (block.T @ previous)
    q, _ = np.linalg.qr(power)
    small = q.T @ block  # (p, m): the block's coordinates in the new subspace
    u, s, _ = np.linalg.svd(small, full_matrices=False)
    return q @ u, s


def group_subspaces(
    trajectories: np.ndarray,
    bounds: np.ndarray,
    p: int,
    previous: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Grassmann point of every contiguous group (paper Eq. 12, ``f_g``).

    Parameters
    ----------
    trajectories : ndarray of shape (3F, P)
        Trajectory matrix S with columns in group order.
    bounds : ndarray of shape (K + 1,), int
        Group i is ``trajectories[:, bounds[i]:bounds[i + 1]]``; every group has >= p columns.
    p : int
        Subspace dimension.
    previous : ndarray of shape (K, 3F, p), optional
        Bases of the previous iteration; when given, one refinement step is taken per group
        (:func:`refine_subspace`) instead of an exact decomposition (:func:`top_subspace`).

    Returns
    -------
    bases : ndarray of shape (K, 3F, p)
    singular_values : ndarray of shape (K, p)
    """
    n_groups = len(bounds) - 1
    n = trajectories.shape[0]
    bases = np.empty((n_groups, n, p))
    singular_values = np.empty((n_groups, p))
    for i in range(n_groups):
        block = trajectories[:, bounds[i] : bounds[i + 1]]
        if previous is None:
            bases[i], singular_values[i] = top_subspace(block, p)
        else:
            bases[i], singular_values[i] = refine_subspace(block, previous[i])
    return bases, singular_values


def project_groups(
    trajectories: np.ndarray,
    bounds: np.ndarray,
    bases: np.ndarray,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Local reconstruction ``f_s`` (paper Eq. 14): each column projected on its group's span.

    For a group's own top-p basis this is its best rank-p approximation ``Phi Sigma V^T``.

    Parameters
    ----------
    trajectories : ndarray of shape (3F, P)
    bounds : ndarray of shape (K + 1,)
    bases : ndarray of shape (K, 3F, p)
    out : ndarray of shape (3F, P), optional
        Where to write the result; may be ``trajectories`` itself (each block is read whole
        before it is overwritten).

    Returns
    -------
    ndarray of shape (3F, P)
    """
    if out is None:
        out = np.empty_like(trajectories)
    for i in range(len(bounds) - 1):
        block = trajectories[:, bounds[i] : bounds[i + 1]]
        out[:, bounds[i] : bounds[i + 1]] = bases[i] @ (bases[i].T @ block)
    return out


def project_observed(
    trajectories: np.ndarray,
    bounds: np.ndarray,
    bases: np.ndarray,
    observed: np.ndarray,
    *,
    source: np.ndarray | None = None,
    hidden_weight: float = 0.0,
) -> np.ndarray:
    """Local reconstruction of points with unobserved frames, fitted on their observed frames.

    For a point j of group i seen only in some frames, its trajectory in the group's span is
    ``Phi_i c_j`` with ``c_j = argmin sum_{f observed} ||Phi_i,f c - s_j,f||^2`` (``Phi_i,f``
    the 3 x p rows of frame f): the group's subspace, learnt from all its members, carries the
    point through the frames where it is hidden. The orthogonal projection of
    :func:`project_groups` would fit c to the hidden frames' current values too. Columns of
    fully observed points are left as they are. In place, O(F (K + m) p^2) for the m points
    with hidden frames: the K groups' per-frame normal matrices in one batched product, two
    products per group, and one batched p x p solve.

    Parameters
    ----------
    trajectories : ndarray of shape (3F, P)
        Modified in place.
    bounds : ndarray of shape (K + 1,)
    bases : ndarray of shape (K, 3F, p)
    observed : ndarray of shape (F, P), bool
    source : ndarray of shape (3F, m), optional
        The values to fit, for the m points with hidden frames (``~observed.all(axis=0)``), in
        their order; default ``trajectories`` at those points. The loop passes the values
        before the groups' projection: after it, a point's observed frames are in the span
        already and the fit returns the projection unchanged.
    hidden_weight : float, default 0.0
        Weight of the hidden frames in the fit (the observed ones weigh 1): a small weight
        lets the current values there (held by the data and temporal steps) steer the
        coefficients a little instead of not at all.
    """
    n_frames = observed.shape[0]
    partial = np.flatnonzero(~observed.all(axis=0))  # the m points with hidden frames
    if partial.size == 0:
        return trajectories
    p = bases.shape[2]
    # Phi_f^T Phi_f of every group and frame in one batched product, (K, F, p * p).
    frames = bases.reshape(len(bases), n_frames, 3, p)
    frame_normals = (frames.transpose(0, 1, 3, 2) @ frames).reshape(len(bases), n_frames, p * p)
    weights = observed[:, partial].astype(np.float64)  # (F, m)
    if hidden_weight:
        weights += hidden_weight * (1.0 - weights)
    values = trajectories[:, partial] if source is None else source
    block = (values.reshape(n_frames, 3, -1) * weights[:, None, :]).reshape(3 * n_frames, -1)
    normals = np.empty((partial.size, p * p))
    rhs = np.empty((partial.size, p))
    # The points of group i are the slice ``edges[i]:edges[i + 1]`` of ``partial``.
    edges = np.searchsorted(partial, bounds)
    groups = np.flatnonzero(np.diff(edges))
    for i in groups:
        part = slice(edges[i], edges[i + 1])
        normals[part] = weights[:, part].T @ frame_normals[i]
        rhs[part] = (bases[i].T @ block[:, part]).T
    normals = normals.reshape(-1, p, p)
    diagonal = normals.reshape(-1, p * p)[:, :: p + 1]  # a view
    diagonal += 1e-10 * diagonal.sum(axis=1, keepdims=True)
    coefficients = np.linalg.solve(normals, rhs[:, :, None])[:, :, 0]  # (m, p)
    for i in groups:
        part = slice(edges[i], edges[i + 1])
        trajectories[:, partial[part]] = bases[i] @ coefficients[part].T
    return trajectories


def track_and_project(
    trajectories: np.ndarray, bounds: np.ndarray, bases: np.ndarray
) -> np.ndarray:
    """Steps 2 and 9 fused for iterations without regrouping: refine, then project in place.

    Each group's basis takes one orthogonal-iteration step from its previous value
    (``Q = qr(S_i S_i^T Phi_i)``) and the group's columns are replaced by ``Q Q^T S_i``. The
    Rayleigh-Ritz rotation of :func:`refine_subspace` is skipped: the projection depends only
    on the span, and orthogonal iteration converges in span without it. This reads each block
    three times instead of five.

    Parameters
    ----------
    trajectories : ndarray of shape (3F, P)
        Overwritten with the local reconstruction.
    bounds : ndarray of shape (K + 1,)
    bases : ndarray of shape (K, 3F, p)
        Previous bases.

    Returns
    -------
    ndarray of shape (K, 3F, p)
        The refined bases.
    """
    refined = np.empty_like(bases)
    for i in range(len(bounds) - 1):
        block = trajectories[:, bounds[i] : bounds[i + 1]]
        q, _ = np.linalg.qr(block @ (block.T @ bases[i]))
        refined[i] = q
        block[...] = q @ (q.T @ block)
    return refined


def projection_distance_sq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Squared projection distance ``p - ||a^T b||_F^2`` between stacks of Grassmann points.

    Parameters
    ----------
    a, b : ndarray of shape (..., n, p)
        Orthonormal bases (broadcast against each other).

    Returns
    -------
    ndarray of shape (...)
        Values in [0, p].
    """
    overlap = np.einsum("...np,...nq->...pq", a, b)
    p = a.shape[-1]
    return np.clip(p - np.einsum("...pq,...pq->...", overlap, overlap), 0.0, p)


def projection_kernel(bases: np.ndarray) -> np.ndarray:
    """Projection kernel ``Gamma_ij = ||B_i^T B_j||_F^2 = <B_i B_i^T, B_j B_j^T>_F``.

    It is the Gram matrix of the embedded points ``B_i B_i^T`` and therefore PSD (Algorithm 1,
    step 6).

    Parameters
    ----------
    bases : ndarray of shape (K, n, p)
        Orthonormal bases.

    Returns
    -------
    ndarray of shape (K, K)
    """
    n_groups, n, p = bases.shape
    if n * n <= 4 * n_groups * p * p:
        # Small ambient dimension (the low-dimensional manifold): vectorise the projectors.
        projectors = np.einsum("kap,kbp->kab", bases, bases).reshape(n_groups, n * n)
        return projectors @ projectors.T
    # Large ambient dimension: square the pairwise overlaps, a row-block of groups at a time
    # so that memory stays O(chunk * K * p^2).
    flat = bases.transpose(1, 0, 2).reshape(n, n_groups * p)
    kernel = np.empty((n_groups, n_groups))
    chunk = max(1, 2_000_000 // max(1, n_groups * p * p))
    for start in range(0, n_groups, chunk):
        stop = min(n_groups, start + chunk)
        overlaps = flat[:, start * p : stop * p].T @ flat  # ((stop-start) p, K p)
        kernel[start:stop] = (overlaps**2).reshape(stop - start, p, n_groups, p).sum(axis=(1, 3))
    return kernel
