"""Hidden tracks filled from their neighbours, where a point's own observations do not fix them.

The low-rank model of W (:class:`moju_core.completion.missing.LowRank`) predicts a point's hidden
entries
from its column, which is fitted on the point's observed frames. A track that ends early (a
point lost at frame 5 of 99) does not determine that column: on a face with 10 % of the tracks
lost from a random frame on, the model's error at those tracks' hidden entries was 0.33 of the
tracks' RMS, against 0.012 at the other hidden entries.

Its neighbours on the surface do move like it. So the model's values of W are corrected in two
steps, each from the well-seen points (:func:`moju_core.completion.missing.well_seen`), in the
neighbours' current values, with the weights that best reproduce the point's observed image
positions from its neighbours' (the local reconstruction weights of locally linear embedding,
Roweis and Saul 2000). The weights sum to one, so the combination is a point of the
neighbours' local affine hull and the model's translation carries over; a surface that is
locally close to affine in its deformation keeps the same weights in every frame.

1. A well-seen point's unreliable entries (:func:`moju_core.completion.missing.trusted_entries`
false)
   take the combination of its neighbours' values there; its other entries keep the model's.
   Its neighbours are, before any other, points that are reliable wherever it is unreliable.
   The model's unreliable entries of well-seen points can be far off: on a face under a band
   over 20 % of the width (seed 3, 2,000 points) their error was 2.5 times the tracks' RMS,
   0.70 once corrected. Where one of the neighbours is unreliable at that frame as well, an
   entry next to an observed frame of the point takes the point's track interpolated across
   the gap instead (:func:`_interpolate_past_unreliable`).
2. Every other point with an unreliable entry takes the combination in all its frames: the
   points seen in fewer than half the frames, whose own observations do not fix their column.

A well-seen point keeps the model's values where they are reliable: it is fitted on as many
frames as it predicts. Under a wide occluder (a band over 30 % of the width with 15 % of the
tracks lost, 1,000 points) replacing every frame of every point with an unreliable entry
replaced 70-90 % of the points of the paper and the cloth from the few never occluded, and
their e3D doubled (paper seed 0: 0.072 -> 0.153; with the two steps 0.036).

Neighbours are chosen by their image trajectories, not by one frame: candidates are the
nearest well-seen points in the image at the point's first, middle and last observed frames (a
k-d tree per frame), and of those the :data:`NEIGHBOURS` with the closest positions over all
the point's observed frames are kept. Where a turning surface overlaps itself in the image,
the nearest points in a single frame can lie on the far side (on a face, 0.85-0.97 of its
size away in 3D), and a single frame's neighbours gave one point 20 times the average error.

Cost, for n filled points of F frames, P points, rank r: a k-d tree of the well-seen points per
frame used (O(F P log P)), the candidates' trajectories O(F n c r) for c candidates, the weights
O(F n k^2), and the model's values O(F P r); nothing P x P.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from moju_core.completion import gaps
from moju_core.completion.missing import LowRank, expand_mask, well_seen

__all__ = ["NEIGHBOURS", "borrow_values"]

#: Neighbours whose columns are combined: a few times the three coordinates a point's
#: neighbourhood must span; 4, 8 and 16 gave about the same error at hidden entries.
#: Held-out check: benchmarks/notes/2026-12-06-rule-ablation.md.
NEIGHBOURS = 8
#: Candidates per frame searched, as a multiple of :data:`NEIGHBOURS` + 1 (a well-seen point is
#: among its own candidates).
CANDIDATE_FACTOR = 4
#: Ridge of the weights' normal equations, relative to their mean diagonal: it keeps the
#: weights defined when a point is seen in fewer frames than it has neighbours.
WEIGHT_RIDGE = 1e-3
#: Entries of the (2F, points, candidates) arrays processed at once.
_BLOCK_ENTRIES = 2_000_000


def borrow_values(
    model: LowRank,
    W: np.ndarray,
    visibility: np.ndarray,
    reliable: np.ndarray,
    noise: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The model's values of W with the unreliable ones taken from the points' neighbours.

    Parameters
    ----------
    model : LowRank
        Fitted on the observed entries (:func:`moju_core.completion.missing.complete`).
    W : ndarray of shape (2F, P)
        Measurements (finite values, e.g. 0.0, at the unobserved entries).
    visibility : ndarray of shape (F, P), bool
        True where observed.
    reliable : ndarray of shape (F, P), bool
        The entries the model predicts well (:func:`moju_core.completion.missing.trusted_entries`).
    noise : float, default 0.0
        Variance of the noise in an entry of W
        (:func:`moju_core.completion.missing.observed_noise_variance`):
        the weights' ridge (:func:`_affine_weights`).

    Returns
    -------
    values : ndarray of shape (2F, P)
        ``model.values()`` with the unreliable entries of the well-seen points and every
        entry of the other points with an unreliable entry replaced (none when no point is
        well seen).
    borrowed : ndarray of shape (P,), bool
        The points whose every entry was replaced.
    """
    values = model.values()
    seen = well_seen(visibility)
    reference = np.flatnonzero(seen)
    unreliable = ~reliable & ~visibility
    partial = np.flatnonzero(seen & unreliable.any(axis=0))
    if partial.size and reference.size > 1:
        combined, chosen = _combine(
            model, values, W, visibility, partial, reference, noise, unreliable
        )
        seen_partial = visibility[:, partial]
        _interpolate_past_unreliable(combined, chosen, W[:, partial], seen_partial, reliable)
        rows = expand_mask(unreliable[:, partial])
        block = values[:, partial]
        block[rows] = combined[rows]
        values[:, partial] = block
    lost = np.flatnonzero(~seen & unreliable.any(axis=0))
    borrowed = np.zeros(W.shape[1], dtype=bool)
    if lost.size and reference.size:
        values[:, lost] = _combine(model, values, W, visibility, lost, reference, noise)[0]
        borrowed[lost] = True
    return values, borrowed


def _combine(
    model: LowRank,
    values: np.ndarray,
    W: np.ndarray,
    visibility: np.ndarray,
    points: np.ndarray,
    reference: np.ndarray,
    noise: float,
    unreliable: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Each point's affine combination of its neighbours' ``values``, (2F, n), and the
    neighbours, (n, k).

    The neighbours are reference points other than the point itself; with ``unreliable``
    ((F, P) bool), those unreliable at none of the point's unreliable frames come first.
    """
    k = min(NEIGHBOURS, reference.size - int(unreliable is not None))
    candidates = _candidates(model, W, visibility, points, reference, CANDIDATE_FACTOR * (k + 1))
    combined = np.empty((W.shape[0], points.size))
    picked = np.empty((points.size, k), dtype=np.int64)
    step = _block(W.shape[0], candidates.shape[1])
    for start in range(0, points.size, step):
        block = slice(start, start + step)
        chosen, rows = points[block], expand_mask(visibility[:, points[block]])
        avoid = None
        if unreliable is not None:
            avoid = _conflicts(unreliable, chosen, candidates[block])
        neighbours = _closest(values, W[:, chosen], rows, candidates[block], k, chosen, avoid)
        weights = _affine_weights(values[:, neighbours.ravel()], W[:, chosen], rows, k, noise)
        combined[:, block] = np.einsum("rnk,nk->rn", values[:, neighbours], weights)
        picked[block] = neighbours
    return combined, picked


def _interpolate_past_unreliable(
    combined: np.ndarray,
    neighbours: np.ndarray,
    tracks: np.ndarray,
    visibility: np.ndarray,
    reliable: np.ndarray,
) -> None:
    """Next to an observed frame of a point and where one of its neighbours is unreliable
    itself, the point's track interpolated linearly across the gap instead of the
    combination, in place.

    The combination carries its neighbours' errors: on the paper under the closing occlusion
    the band hides 60 % of the points in some frames, whose rows the observed points do not
    determine, and the neighbours' values there are as far off as the point's. One frame
    from an observed frame (seeds 66, 67, 70-72, noise 0 and 1 %) the combination was
    0.31-1.41 of the tracks' RMS off at the untrusted entries of well-seen points, the
    interpolation 0.03-0.32 (but for 2 entries); two to seven frames into a gap the
    interpolation was as often the worse (0.09-0.95 against 0.17-0.50), so the combination
    stays there, and before a track's first or after its last observed frame.

    combined : (2F, n), updated; neighbours : (n, k) point indices; tracks : (2F, n), read at
    the observed entries of ``visibility`` (F, n); reliable : (F, P) bool, the observed and
    trusted entries of every point.
    """
    if neighbours.shape[1] == 0:
        return
    shaky = np.empty(visibility.shape, dtype=bool)  # (F, n): a neighbour unreliable there
    step = _block(visibility.shape[0], neighbours.shape[1])
    for start in range(0, neighbours.shape[0], step):
        block = slice(start, start + step)
        shaky[:, block] = ~reliable[:, neighbours[block]].all(axis=2)
    parts = gaps.pieces(tracks, combined, visibility)  # track: interpolated minus combined
    use = expand_mask(shaky) & parts.inside & (parts.distance == 1)
    combined[use] += parts.track[use]


def _conflicts(unreliable: np.ndarray, points: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Whether each candidate is unreliable at one of its point's unreliable frames, (n, c)."""
    both = unreliable[:, candidates] & unreliable[:, points][:, :, None]
    return both.any(axis=0)


def _block(n_rows: int, n_candidates: int) -> int:
    """Points per block, so that the (2F, points, candidates) arrays stay small."""
    return max(1, _BLOCK_ENTRIES // (n_rows * n_candidates))


def _candidates(
    model: LowRank,
    W: np.ndarray,
    visibility: np.ndarray,
    points: np.ndarray,
    reference: np.ndarray,
    per_frame: int,
) -> np.ndarray:
    """Nearest reference points in the image at each point's first, middle and last observed
    frames, (n, 3 c) indices (c = ``per_frame``, capped by the reference points)."""
    per_frame = min(per_frame, reference.size)
    seen = [np.flatnonzero(visibility[:, j]) for j in points]
    roles = [np.array([frames[i] for frames in seen]) for i in (0, -1)]
    roles.append(np.array([frames[frames.size // 2] for frames in seen]))
    pools = []
    for frames in roles:
        pool = np.empty((points.size, per_frame), dtype=np.int64)
        for frame in np.unique(frames):
            rows = slice(2 * frame, 2 * frame + 2)
            positions = model.left[rows] @ model.right[:, reference]
            at = frames == frame
            query = W[rows, points[at]] - model.translation[rows, None]
            _, nearest = cKDTree(positions.T).query(query.T, k=per_frame)
            pool[at] = reference[np.asarray(nearest).reshape(-1, per_frame)]
        pools.append(pool)
    return np.hstack(pools)


def _closest(
    values: np.ndarray,
    tracks: np.ndarray,
    rows: np.ndarray,
    candidates: np.ndarray,
    k: int,
    points: np.ndarray,
    avoid: np.ndarray | None,
) -> np.ndarray:
    """Of each point's candidates (repeats allowed), the k distinct ones other than the point
    whose values are closest to the point's observed positions over its observed rows, those
    not marked in ``avoid`` first, (n, k).

    values : (2F, P); tracks : (2F, n); rows : (2F, n) bool, the observed rows;
    candidates : (n, c); points : (n,); avoid : (n, c) bool or None.
    """
    order = np.argsort(candidates, axis=1, kind="stable")
    candidates = np.take_along_axis(candidates, order, axis=1)
    n, c = candidates.shape
    near = values[:, candidates.ravel()].reshape(-1, n, c)
    distance = np.einsum("rnc,rn->nc", (near - tracks[:, :, None]) ** 2, rows.astype(float))
    excluded = np.zeros_like(candidates, dtype=bool)
    excluded[:, 1:] = candidates[:, 1:] == candidates[:, :-1]
    excluded |= candidates == points[:, None]
    rank = excluded * 2
    if avoid is not None:
        rank = np.maximum(rank, np.take_along_axis(avoid, order, axis=1))
    chosen = np.lexsort((distance, rank), axis=1)[:, :k]
    return np.take_along_axis(candidates, chosen, axis=1)


def _affine_weights(
    values: np.ndarray, tracks: np.ndarray, rows: np.ndarray, k: int, noise: float = 0.0
) -> np.ndarray:
    """Weights summing to one that best reproduce each point's observed positions from its
    neighbours' model positions, ``min ||sum_i w_i (x_i - y)||^2`` over the observed rows,
    with a ridge, (n, k).

    The ridge is :data:`WEIGHT_RIDGE` of the mean diagonal, plus the noise variance times the
    number of observed rows: what noise of that variance in the neighbours' positions would add
    to the diagonal. Without it, the weights of a noisy point seen in a few frames fit its noise
    with large weights of opposite signs, which the combination carries into the other frames
    (a face at 1 % noise, tracks lost from a random frame on: 0.17 of the tracks' RMS off at
    the filled entries, 0.035 with it).

    values : (2F, n k) neighbours' model positions; tracks : (2F, n); rows : (2F, n) bool;
    noise : the noise variance of an entry of W.
    """
    n = tracks.shape[1]
    offsets = (values.reshape(-1, n, k) - tracks[:, :, None]) * rows[:, :, None]
    gram = np.einsum("rnk,rnl->nkl", offsets, offsets)
    ridge = WEIGHT_RIDGE * np.trace(gram, axis1=1, axis2=2) / k + 1e-300
    ridge += noise * rows.sum(axis=0)
    gram += ridge[:, None, None] * np.eye(k)
    weights = np.linalg.solve(gram, np.ones((n, k, 1)))[:, :, 0]
    return weights / weights.sum(axis=1, keepdims=True)
