"""Grouping: initial local groups, the spatial similarity graph, spectral clustering of
Grassmann points and the regrouping of trajectories (Algorithm 1, steps 4 and 8, ``f_p``)."""

from __future__ import annotations

import warnings

import numpy as np
from sklearn.cluster import KMeans, SpectralClustering
from sklearn.neighbors import NearestNeighbors

from moju_core.loop.grassmann import projection_distance_sq

#: Up to this many rows (2F) the principal directions of :func:`track_features` come from the
#: 2F x 2F Gram matrix, O(F^2 P + F^3); beyond it from a randomized range finder, O(F P).
FEATURES_GRAM_MAX_ROWS = 1000
#: Extra columns and power iterations of that range finder.
FEATURES_OVERSAMPLING = 10
FEATURES_POWER_ITERATIONS = 4


def track_features(tracks: np.ndarray, n_components: int = 12) -> np.ndarray:
    """Low-dimensional coordinates of every point's 2D track, for k-means and neighbour search.

    The tracks lie close to a rank-3K subspace, so Euclidean distances between tracks are kept
    almost exactly by their coordinates in the top principal directions, at a fraction of the
    cost of working with 2F-dimensional vectors. The principal directions come from the
    2F x 2F Gram matrix up to ``FEATURES_GRAM_MAX_ROWS`` rows; for longer sequences from a
    randomized range finder (seeded: a block of c + 10 columns, 4 power iterations, and the
    SVD of its (c + 10, P) projection of the tracks), which costs O(F P c).

    Parameters
    ----------
    tracks : ndarray of shape (2F, P)
        Centred measurement matrix W.
    n_components : int
        Number of principal directions kept (capped at 2F).

    Returns
    -------
    ndarray of shape (P, c)
    """
    c = min(n_components, tracks.shape[0])
    if tracks.shape[0] > FEATURES_GRAM_MAX_ROWS:
        return (_principal_directions(tracks, c).T @ tracks).T
    _, vectors = np.linalg.eigh(tracks @ tracks.T)
    return (vectors[:, ::-1][:, :c].T @ tracks).T


def _principal_directions(tracks: np.ndarray, c: int) -> np.ndarray:
    """The top c left singular vectors of tracks (m, n), approximately, shape (m, c)."""
    rng = np.random.default_rng(0)
    width = min(c + FEATURES_OVERSAMPLING, *tracks.shape)
    block = np.linalg.qr(tracks @ rng.standard_normal((tracks.shape[1], width)))[0]
    for _ in range(FEATURES_POWER_ITERATIONS):
        block = np.linalg.qr(tracks @ (tracks.T @ block))[0]
    left, _, _ = np.linalg.svd(block.T @ tracks, full_matrices=False)
    return block @ left[:, :c]


#: The initial k-means is fitted on at most this many tracks per group (a random sample) and
#: then assigns every track to its nearest centre. Lloyd's iterations over all tracks cost
#: O(P K) each; at 100,000 tracks and 600 groups the full fit took 9.4 s (one thread), the
#: sampled one 1.8 s with a 4.5 % larger k-means objective. The groups are only a start: the
#: regrouping steps move trajectories between them from the first iteration on.
KMEANS_SAMPLE_PER_GROUP = 50


def initial_labels(features: np.ndarray, n_groups: int, min_size: int, seed: int) -> np.ndarray:
    """k-means++ groups of the tracks; groups smaller than ``min_size`` are dissolved.

    With more than ``KMEANS_SAMPLE_PER_GROUP * n_groups`` tracks the centres are fitted on a
    random sample of that size (seeded), and every track joins its nearest centre.

    Parameters
    ----------
    features : ndarray of shape (P, c)
        Track coordinates (:func:`track_features`).
    n_groups : int
        Requested number of groups.
    min_size : int
        Smallest allowed group.
    seed : int

    Returns
    -------
    ndarray of shape (P,), int64
        Labels 0..K'-1 with ``K' <= n_groups`` (K' < n_groups when small groups were dissolved
        into their nearest large neighbours).
    """
    kmeans = KMeans(n_clusters=n_groups, init="k-means++", n_init=1, random_state=seed)
    sample_size = KMEANS_SAMPLE_PER_GROUP * n_groups
    if len(features) > sample_size:
        sample = np.random.default_rng(seed).choice(len(features), sample_size, replace=False)
        labels = kmeans.fit(features[sample]).predict(features).astype(np.int64)
    else:
        labels = kmeans.fit_predict(features).astype(np.int64)
    centers = kmeans.cluster_centers_
    sizes = np.bincount(labels, minlength=n_groups)
    large = np.flatnonzero(sizes >= min_size)
    small_points = np.flatnonzero(sizes[labels] < min_size)
    if small_points.size:
        nearest = NearestNeighbors(n_neighbors=1).fit(centers[large])
        _, idx = nearest.kneighbors(features[small_points])
        labels[small_points] = large[idx[:, 0]]
    _, labels = np.unique(labels, return_inverse=True)
    return labels.astype(np.int64)


def neighbour_edges(centroids: np.ndarray, n_neighbors: int) -> np.ndarray:
    """Symmetrised k-nearest-neighbour graph of the groups' image centroids.

    Parameters
    ----------
    centroids : ndarray of shape (K, c)
        Mean track features of each group.
    n_neighbors : int
        Neighbours per group (capped at K - 1).

    Returns
    -------
    ndarray of shape (E, 2), int64
        Undirected edges ``i < j``.
    """
    k = min(n_neighbors, len(centroids) - 1)
    if k < 1:
        return np.empty((0, 2), dtype=np.int64)
    _, idx = NearestNeighbors(n_neighbors=k + 1).fit(centroids).kneighbors(centroids)
    rows = np.repeat(np.arange(len(centroids)), k)
    cols = idx[:, 1:].ravel()
    pairs = np.sort(np.stack([rows, cols], axis=1), axis=1)
    return np.unique(pairs, axis=0).astype(np.int64)


def similarity_graph(bases: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """``w_ij = exp(-d_g^2(Phi_i, Phi_j))`` on the given edges, zero elsewhere (step 4).

    Parameters
    ----------
    bases : ndarray of shape (K, n, p)
    edges : ndarray of shape (E, 2)

    Returns
    -------
    ndarray of shape (K, K)
        Symmetric with zero diagonal.
    """
    n_groups = len(bases)
    weights = np.zeros((n_groups, n_groups))
    if len(edges):
        values = np.exp(-projection_distance_sq(bases[edges[:, 0]], bases[edges[:, 1]]))
        weights[edges[:, 0], edges[:, 1]] = values
        weights[edges[:, 1], edges[:, 0]] = values
    return weights


def cluster_groups(coefficients: np.ndarray, n_clusters: int, seed: int) -> np.ndarray:
    """Spectral clustering of the Grassmann points with affinity ``(|C| + |C^T|) / 2``.

    The clusters are read off the spectral embedding by the QR-based rule ``cluster_qr``
    (Damle, Minden and Ying 2019) instead of k-means with 10 restarts: deterministic, and
    0.07 s instead of 0.25 s per call at K = 600 (one thread) with the same e3D on the
    project's sequences.

    Parameters
    ----------
    coefficients : ndarray of shape (K, K)
        LRR coefficient matrix C.
    n_clusters : int
        Number of clusters, < K.
    seed : int

    Returns
    -------
    ndarray of shape (K,), int64
    """
    affinity = 0.5 * (np.abs(coefficients) + np.abs(coefficients.T))
    model = SpectralClustering(
        n_clusters=n_clusters, affinity="precomputed", random_state=seed, assign_labels="cluster_qr"
    )
    with warnings.catch_warnings():
        # A graph that is not fully connected is expected here (distinct subspaces); the
        # embedding is still meaningful for clustering.
        warnings.simplefilter("ignore", UserWarning)
        return model.fit_predict(affinity).astype(np.int64)


def regroup(
    trajectories: np.ndarray,
    labels: np.ndarray,
    bases: np.ndarray,
    group_clusters: np.ndarray,
    min_size: int,
    min_gain: float = 0.05,
) -> np.ndarray:
    """Move each trajectory to the best-fitting group of its cluster (step 8, ``f_p``).

    A trajectory ``x`` of group g may move to any group h with
    ``group_clusters[h] == group_clusters[g]``; it goes to the one with the smallest residual
    ``||x - Phi_h Phi_h^T x||`` (equivalently the largest ``||Phi_h^T x||``), provided that
    it lowers the squared residual by at least the fraction ``min_gain``. Moves that would
    leave a group with fewer than ``min_size`` members are undone, smallest gains first, so
    the number of groups never changes.

    Parameters
    ----------
    trajectories : ndarray of shape (n, P)
        Columns are trajectories (any column order).
    labels : ndarray of shape (P,)
        Current group of every column.
    bases : ndarray of shape (K, n, p)
    group_clusters : ndarray of shape (K,)
        Cluster of every group.
    min_size : int
    min_gain : float
        Smallest relative reduction of the squared residual that justifies a move.

    Returns
    -------
    ndarray of shape (P,), int64
        New labels.
    """
    n_groups, n, p = bases.shape
    new = labels.copy()
    gain = np.zeros(len(labels))
    point_clusters = group_clusters[labels]
    for cluster in np.unique(group_clusters):
        members = np.flatnonzero(group_clusters == cluster)
        if len(members) < 2:
            continue
        points = np.flatnonzero(point_clusters == cluster)
        flat = bases[members].transpose(1, 0, 2).reshape(n, len(members) * p)
        energy = ((flat.T @ trajectories[:, points]) ** 2).reshape(len(members), p, -1).sum(1)
        best = np.argmax(energy, axis=0)
        current = np.searchsorted(members, labels[points])
        current_energy = energy[current, np.arange(len(points))]
        best_energy = energy[best, np.arange(len(points))]
        norms = np.einsum("np,np->p", trajectories[:, points], trajectories[:, points])
        current_residual = norms - current_energy
        best_residual = norms - best_energy
        # Hysteresis: a trajectory fitted about equally well by two groups would otherwise
        # flip between them at every regrouping and keep the ADMM gap from closing.
        moves = best_residual < (1.0 - min_gain) * current_residual
        new[points[moves]] = members[best[moves]]
        gain[points[moves]] = current_residual[moves] - best_residual[moves]
    for _ in range(n_groups + 1):
        sizes = np.bincount(new, minlength=n_groups)
        short = np.flatnonzero(sizes < min_size)
        if not short.size:
            break
        for g in short:
            deficit = min_size - sizes[g]
            left = np.flatnonzero((labels == g) & (new != g))
            undo = left[np.argsort(gain[left])[:deficit]]
            new[undo] = g
            gain[undo] = 0.0
    return new
