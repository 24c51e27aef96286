"""Groups of points cut off from the rest of the surface in an image, held within reach of it.

In each image the edges whose two ends are seen split the seen points into connected groups
(:func:`~moju_core.priors.neighbour_graph.largest_groups`). The cone program relates the depths
of two points only through a path of such edges, so a group cut off from the largest one (a
flap turning edge-on while its links to the sheet are hidden) is bounded by its own few edges
only, and the maximum-depth heuristic pushes it as far as they allow: several times the
surface's depth when the group is seen edge-on, where its image is short.

The hidden links still bound it. Every edge keeps its length ``l_e`` in every image, so two
points are never farther apart than their geodesic distance on the edge graph (the shortest
path over all edges, with lengths ``l_e``), whatever the image sees. :func:`hold_cut_off_groups`
scales each cut-off group's depths along its rays by one factor ``s`` (its shape and its own
edges are kept, its edges only shorten) to the largest ``s <= 1`` at which every point of the
group is within its geodesic distance of every point of the largest group: the maximum-depth
heuristic with those bounds added, restricted to moving the group as a whole. The lengths are
estimates: the bounds are loosened by the program's own measure of how far its edges fall
short of their lengths, and a group whose bounds contradict one another (no ``s`` meets them
all: on tracked cloth, groups of 40-70 anchors cut off by a hidden fold, whose own edges set
their depth well) keeps its depths.

Cost: one Dijkstra run from each point that is ever cut off, ``O(C (E + A log A))`` for ``C``
such points, then ``O(C_f A)`` per image for the ``C_f`` points cut off in it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from moju_core.priors.dense_depth import homogeneous
from moju_core.priors.neighbour_graph import group_labels, largest_groups

__all__ = ["hold_cut_off_groups"]


def hold_cut_off_groups(
    rays: np.ndarray,
    seen: np.ndarray,
    edges: np.ndarray,
    depths: np.ndarray,
    lengths: np.ndarray,
    slack: float = 0.0,
) -> np.ndarray:
    """Depths with every cut-off group within its geodesic distance of its image's largest group.

    Parameters
    ----------
    rays : ndarray of shape (F, P, 2)
        Normalised image coordinates.
    seen : ndarray of shape (F, P), bool
        True where seen.
    edges : ndarray of shape (E, 2), int
        The neighbour graph the depths were solved on.
    depths : ndarray of shape (F, P)
        The cone program's depths, in the unit of ``lengths``; NaN where it set none.
    lengths : ndarray of shape (E,)
        Edge lengths ``l_e`` (NaN for an edge never seen whole).
    slack : float, default 0
        How far the solved edges fall short of their lengths, relative to them (the cone
        program's mean consistency slack): the geodesic bounds are loosened by ``1 + slack``,
        so that a group is moved only by more than the lengths' own inconsistency.

    Returns
    -------
    depths : ndarray of shape (F, P)
        A copy; each cut-off group scaled by its factor. A group that no factor brings within
        its bounds (bounds that contradict one another) keeps its depths.
    """
    placed = largest_groups(seen & np.isfinite(depths), edges)
    cut_off = seen & np.isfinite(depths) & ~placed
    out = depths.copy()
    if not cut_off.any():
        return out
    sources = np.flatnonzero(cut_off.any(axis=0))
    geodesic = _geodesics(edges, lengths, seen.shape[1], sources)  # (C, P)
    row_of = np.full(seen.shape[1], -1)
    row_of[sources] = np.arange(sources.size)
    points = depths[..., None] * homogeneous(rays)  # (F, P, 3)
    for f in np.flatnonzero(cut_off.any(axis=1)):
        for group in _groups(cut_off[f], edges):
            bounds = (1.0 + slack) * geodesic[row_of[group]][:, placed[f]]  # (G, M)
            factor = _largest_factor(points[f, group], points[f, placed[f]], bounds)
            if factor < 1.0:
                out[f, group] = depths[f, group] * factor
    return out


def _geodesics(
    edges: np.ndarray, lengths: np.ndarray, n_points: int, sources: np.ndarray
) -> np.ndarray:
    """Shortest-path lengths (len(sources), P) over the edges of finite length; inf where
    no path joins two points."""
    usable = np.isfinite(lengths)
    i, j = edges[usable, 0], edges[usable, 1]
    graph = sp.coo_matrix((lengths[usable], (i, j)), shape=(n_points, n_points)).tocsr()
    return np.atleast_2d(dijkstra(graph, directed=False, indices=sources))


def _groups(members: np.ndarray, edges: np.ndarray) -> list[np.ndarray]:
    """Connected groups (point indices) of the ``members`` (P,) bool over the edges with both
    ends members."""
    label = group_labels(members, edges)
    return [np.flatnonzero(members & (label == g)) for g in np.unique(label[members])]


def _largest_factor(group: np.ndarray, rest: np.ndarray, bounds: np.ndarray) -> float:
    """The largest ``s <= 1`` with ``||s a - b|| <= g`` for every point ``a`` of ``group``
    (G, 3), ``b`` of ``rest`` (M, 3) and their bound ``g`` (G, M); NaN if none.

    Each pair allows an interval of ``s``, the roots of ``s^2 |a|^2 - 2 s a.b + |b|^2 - g^2``;
    the factor is the top of their intersection, capped at 1.
    """
    finite = np.isfinite(bounds)
    if not finite.any():
        return 1.0
    aa = np.sum(group**2, axis=1)[:, None]
    ab = group @ rest.T
    bb = np.sum(rest**2, axis=1)[None, :]
    disc = ab**2 - aa * (bb - bounds**2)
    if np.any(finite & (disc < 0)):
        return float("nan")
    root = np.sqrt(np.where(finite, disc, 0.0))
    low = np.max(np.where(finite, (ab - root) / aa, -np.inf))
    high = np.min(np.where(finite, (ab + root) / aa, np.inf))
    if low > high or high <= 0:
        return float("nan")
    return float(min(1.0, high))
