"""The column space of an exactly low-rank W with missing entries, from windows of frames.

Within a window of consecutive frames, the points observed in every one of its frames form a
complete block of W. If W is exactly of rank k (noise-free tracks of a deformation that is a
combination of a few shape bases), the block's column space is the window's rows of W's
column space ``col(W)``, once the block has k independent columns. The windows overlap, so
the rows they share tie them together: ``col(W)`` is the k-dimensional subspace whose
restriction to every window lies in that window's block space, found as the eigenvectors of
the k smallest eigenvalues of ``sum_w E_w^T (I - U_w U_w^T) E_w`` (``E_w`` selects the
window's rows, ``U_w`` its block's orthonormal column basis). The matrix is banded (a window
couples only its own rows), so the eigenvectors come from a banded solver.

This is a starting point, not the fit: a window whose points miss a weak direction of W
(an occluder hides the part of the object that moves in it) constrains it wrongly, and
:func:`moju_core.completion.exact_model.exact_model` refines each candidate subspace by alternating
least
squares on all observed entries, then keeps the first that predicts held-out entries. Where
W is not exactly of low rank (noise), some window's block has no gap in its spectrum and
:func:`column_spaces` yields nothing.

Cost: one SVD per window, O(L^2 n) for L frames and n points, over about 3F / L windows; the
banded eigenproblem O(F L^2). Nothing F x F or P x P is formed.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from scipy.linalg import eig_banded

from moju_core.spectrum import RANK_FLOOR

#: Window lengths tried, longest first, in frames; the windows start every third of a length.
#: Every length whose windows all show a low rank gives a candidate. Longer windows see more of
#: the deformation (a short window can miss a weak direction), but fewer points are observed
#: in all of their frames. Held-out check: benchmarks/notes/2026-12-06-rule-ablation.md.
WINDOW_LENGTHS = (40, 30, 20, 12)
#: A block shows a low rank when its exact rank (singular values above ``RANK_FLOOR`` of the
#: largest) is at most this fraction of its smaller side: noisy tracks then give no candidate,
#: which spares the exact model seconds of ALS that its held-out test would refuse. Held-out
#: check (and its cost on the cloth): benchmarks/notes/2026-12-06-rule-ablation.md.
LOW_RANK_FRACTION = 0.5


#: Directions beyond the windows' largest rank that :func:`column_spaces` returns: W's rank
#: can exceed every window's (a camera that turns slowly within a window leaves its motion
#: short of some directions that other windows see), and a window whose points miss a weak
#: direction leaves the stitched basis short of it. Faces with the sweeping occluder needed up
#: to 2 more than the largest window rank.
EXTRA_DIRECTIONS = 3


def _window_starts(n_frames: int, length: int) -> list[int]:
    """Starts of the windows of ``length`` frames, a third of a length apart, covering all."""
    stride = max(1, length // 3)
    starts = list(range(0, n_frames - length + 1, stride))
    if starts[-1] != n_frames - length:
        starts.append(n_frames - length)
    return starts


def _block_basis(
    W: np.ndarray, visibility: np.ndarray, start: int, length: int
) -> np.ndarray | None:
    """Orthonormal basis (2L, r) of the block of the window's fully observed points, or None
    when the block does not show a low rank (:data:`LOW_RANK_FRACTION`)."""
    points = visibility[start : start + length].all(axis=0)
    block = W[2 * start : 2 * (start + length), points]
    if block.shape[1] == 0:
        return None
    left, singular, _ = np.linalg.svd(block, full_matrices=False)
    rank = int(np.count_nonzero(singular > RANK_FLOOR * singular[0]))
    if rank == 0 or rank > LOW_RANK_FRACTION * min(block.shape):
        return None
    return left[:, :rank]


def _windows(W: np.ndarray, visibility: np.ndarray, length: int) -> list[np.ndarray] | None:
    """The bases of the windows of ``length`` frames, or None if one does not show a low rank."""
    bases = []
    for start in _window_starts(visibility.shape[0], length):
        basis = _block_basis(W, visibility, start, length)
        if basis is None:
            return None
        bases.append(basis)
    return bases


def _stitch(bases: list[np.ndarray], n_rows: int, length: int) -> np.ndarray:
    """The subspaces closest to every window's block space: the eigenvectors (2F, k + e) of
    the k + e smallest eigenvalues of the banded matrix ``sum_w E_w^T (I - U_w U_w^T) E_w``,
    k the windows' largest rank and e = :data:`EXTRA_DIRECTIONS`, in increasing order."""
    rank = min(max(basis.shape[1] for basis in bases) + EXTRA_DIRECTIONS, n_rows)
    width = 2 * length
    # Lower banded storage: banded[i - j, j] = A[i, j] for 0 <= i - j < width.
    banded = np.zeros((width, n_rows))
    offsets = np.arange(width)
    for start, basis in zip(_window_starts(n_rows // 2, length), bases, strict=True):
        block = np.eye(width) - basis @ basis.T
        first = 2 * start
        for diagonal in range(width):
            banded[diagonal, first + offsets[: width - diagonal]] += np.diagonal(block, -diagonal)
    return eig_banded(banded, lower=True, select="i", select_range=(0, rank - 1))[1]


def column_spaces(W: np.ndarray, visibility: np.ndarray) -> Iterator[tuple[np.ndarray, int]]:
    """Candidate orthonormal bases (2F, k) of the column space of an exactly low-rank W.

    One per window length of :data:`WINDOW_LENGTHS` (longest first) whose every window
    shows a low rank; none when W is not exactly of low rank. They differ where a window's
    block misses a weak direction of W (its points, all seen in a band of the object, do not
    move in it): the caller keeps the one that predicts held-out entries.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Measurements (not centred; any values at the unobserved entries).
    visibility : ndarray of shape (F, P), bool
        True where the point is observed.

    Yields
    ------
    (basis, rank) : (ndarray of shape (2F, k + e), int)
        The stitched basis, most consistent direction first (:func:`_stitch`), and k, the
        largest exact rank of the windows' blocks: W's rank is at least k.
    """
    n_frames = visibility.shape[0]
    for length in WINDOW_LENGTHS:
        bases = _windows(W, visibility, length) if length <= n_frames else None
        if bases is not None:
            yield _stitch(bases, W.shape[0], length), max(b.shape[1] for b in bases)
