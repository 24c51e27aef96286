"""Image-space neighbour graphs and spread-out anchor subsets for the surface prior.

The maximum-depth heuristic (:mod:`~moju_core.priors.max_depth`) bounds the 3D distance of
points that are neighbours on the surface. Surface neighbours are taken as image neighbours:
two points that are among each other's ``k`` nearest in the images are assumed close on the
surface too. Folds can make far surface points close in one image, so an edge is kept only if
it is a ``k``-nearest pair in at least half of the frames where both points are seen (stable
neighbours); points tracked only part of the time still get edges from the frames that see them.

Every function here is pure (no globals, no randomness except through ``seed``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["group_labels", "largest_groups", "neighbour_edges", "spread_anchors", "visibility_of"]


def visibility_of(rays: np.ndarray, visibility: np.ndarray | None = None) -> np.ndarray:
    """The (F, P) bool mask of seen entries: ``visibility`` and finite rays.

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
        Normalised image coordinates, NaN where not seen.
    visibility : ndarray of shape (F, P), bool, optional
        Declared visibility; ``None`` means every finite ray is seen.
    """
    rays = np.asarray(rays, dtype=np.float64)
    if rays.ndim != 3 or rays.shape[2] != 2:
        raise ValueError(f"rays must have shape (F, P, 2), got {rays.shape}")
    seen = np.all(np.isfinite(rays), axis=2)
    if visibility is not None:
        visibility = np.asarray(visibility, dtype=bool)
        if visibility.shape != seen.shape:
            raise ValueError(f"visibility must have shape {seen.shape}, got {visibility.shape}")
        seen &= visibility
    return seen


def neighbour_edges(
    rays: np.ndarray,
    visibility: np.ndarray | None = None,
    *,
    k: int = 8,
    min_share: float = 0.5,
) -> np.ndarray:
    """Undirected edges between stable image neighbours.

    For each frame, every seen point is joined to its ``k`` nearest seen points in that image;
    an edge is kept when it appears in at least ``min_share`` of the frames where both of its
    points are seen (and at least once).

    Cost: ``O(F P k log P)`` time (one k-d tree per frame), ``O(F P k)`` memory; never ``P^2``.

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
        Normalised image coordinates (dimensionless), NaN where not seen.
    visibility : ndarray of shape (F, P), bool, optional
        True where seen; combined with the finiteness of ``rays``.
    k : int, default 8
        Neighbours per point and frame.
    min_share : float in [0, 1], default 0.5
        Fraction of co-visible frames in which the pair must be ``k``-nearest.

    Returns
    -------
    edges : ndarray of shape (E, 2), int64
        Sorted pairs ``i < j``, sorted lexicographically.
    """
    rays = np.asarray(rays, dtype=np.float64)
    seen = visibility_of(rays, visibility)
    n_frames, n_points = seen.shape
    if k < 1:
        raise ValueError(f"k must be at least 1, got {k}")
    keys = []
    for f in range(n_frames):
        ids = np.flatnonzero(seen[f])
        if ids.size < 2:
            continue
        kk = min(k, ids.size - 1)
        _, nn = cKDTree(rays[f, ids]).query(rays[f, ids], kk + 1)
        a = np.repeat(ids, kk)
        b = ids[nn[:, 1:].ravel()]
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        # One key per undirected pair and frame (a mutual pair counts once per frame).
        keys.append(np.unique(lo * n_points + hi))
    if not keys:
        return np.zeros((0, 2), dtype=np.int64)
    pair_keys, counts = np.unique(np.concatenate(keys), return_counts=True)
    edges = np.stack([pair_keys // n_points, pair_keys % n_points], axis=1).astype(np.int64)
    together = np.sum(seen[:, edges[:, 0]] & seen[:, edges[:, 1]], axis=0)
    keep = counts >= np.maximum(1.0, min_share * together)
    return edges[keep]


def spread_anchors(
    rays: np.ndarray, visibility: np.ndarray | None = None, *, n_anchor: int = 200, seed: int = 0
) -> np.ndarray:
    """A subset of points spread over the image, by farthest-point sampling.

    Each point is placed at its position in the frame that sees the most points (its first
    seen position if that frame misses it); the first anchor is drawn with ``seed``, each next
    one is the point farthest from those chosen. Points seen in fewer than two frames are
    not chosen (they carry no inextensibility across frames).

    Cost: ``O(n_anchor P)`` time, ``O(P)`` memory.

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
        Normalised image coordinates, NaN where not seen.
    visibility : ndarray of shape (F, P), bool, optional
        True where seen.
    n_anchor : int, default 200
        Number of anchors; all eligible points when there are fewer.
    seed : int, default 0
        Seed of the first draw.

    Returns
    -------
    anchors : ndarray of shape (A,), int64
        Sorted point indices, ``A = min(n_anchor, eligible points)``.
    """
    rays = np.asarray(rays, dtype=np.float64)
    seen = visibility_of(rays, visibility)
    reference = int(np.argmax(seen.sum(axis=1)))
    first_seen = np.argmax(seen, axis=0)
    frame = np.where(seen[reference], reference, first_seen)
    positions = rays[frame, np.arange(seen.shape[1])]
    eligible = np.flatnonzero(seen.sum(axis=0) >= 2)
    if eligible.size <= n_anchor:
        return eligible.astype(np.int64)
    rng = np.random.default_rng(seed)
    pts = positions[eligible]
    chosen = np.empty(n_anchor, dtype=np.int64)
    chosen[0] = rng.integers(eligible.size)
    dist = np.linalg.norm(pts - pts[chosen[0]], axis=1)
    for a in range(1, n_anchor):
        chosen[a] = int(np.argmax(dist))
        dist = np.minimum(dist, np.linalg.norm(pts - pts[chosen[a]], axis=1))
    return np.sort(eligible[chosen])


def largest_groups(seen: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """The seen entries joined by seen edges to the largest group of their image.

    In each image the edges whose two ends are seen split the seen points into connected
    groups; inextensibility relates the depths of two points only through a path of such
    edges. The largest group of each image (the earliest of equal largest ones, so the choice
    is deterministic) is the one the others are held to
    (:mod:`~moju_core.priors.cut_off_groups`).

    Cost: ``O(F (P + E))`` time, ``O(P + E)`` memory (one image at a time).

    Parameters
    ----------
    seen : ndarray of shape (F, P), bool
        True where the point is seen.
    edges : ndarray of shape (E, 2), int
        Undirected edges between points.

    Returns
    -------
    placed : ndarray of shape (F, P), bool
        ``seen`` restricted to the largest group of each image.
    """
    seen = np.asarray(seen, dtype=bool)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    placed = np.zeros_like(seen)
    for f, row in enumerate(seen):
        if row.any():
            label = group_labels(row, edges)
            sizes = np.bincount(label[row], minlength=label.max() + 1)
            placed[f] = row & (label == np.argmax(sizes))
    return placed


def group_labels(members: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Connected-group label (P,) of every point over the ``edges`` (E, 2) whose two ends are
    ``members`` (P,) bool; a point outside ``members`` is a group of its own. ``O(P + E)``."""
    whole = edges[members[edges[:, 0]] & members[edges[:, 1]]]
    n_points = members.size
    graph = sp.coo_matrix(
        (np.ones(len(whole)), (whole[:, 0], whole[:, 1])), shape=(n_points, n_points)
    )
    return connected_components(graph, directed=False)[1]
