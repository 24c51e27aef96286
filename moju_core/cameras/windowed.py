"""Camera rotations from rigid factorisations of short windows of frames, chained together.

When the camera turns fast compared with how fast the object deforms (a hand-held camera
walking around a sheet of paper that slowly rolls up), a few consecutive frames see an almost
rigid object: Tomasi and Kanade's rigid factorisation of those frames alone recovers their
rotations, up to one orthogonal 3 x 3 transform per window. Sliding the window one frame at a
time and aligning each window with the frames it shares with the previous ones (orthogonal
Procrustes over their rotation rows) chains the windows into rotations for the whole sequence;
every frame's rotation is the average of its windows' (projected back to orthonormal rows).
The chain follows the object's mean orientation, which a deforming object changes; those
rotation errors are largely of the kind a shape can absorb, and the ADMM loop refines these
rotations together with the shapes
(:func:`moju_core.cameras.refinement.fit_rotations_to_shapes`).
Dai et al.'s intersection method instead needs the shapes to be a combination of a few
shape bases, which a rolling sheet or a travelling wave is not with only tens of frames.

Everything here works on the blocks of the row Gram matrix ``W W^T`` near its diagonal
(:class:`RowGram`): they are the windows' Gram matrices, so no pass over the P points is made
after that one product. For short sequences the whole product is cheaper and is formed; for
long ones (motion capture: thousands of frames of tens of markers) only the ``2 (2 reach) + 1``
diagonals within the longest window are computed, O(F P reach) time and O(F reach) memory
instead of O(F^2 P) and O(F^2).

:func:`short_time_rigidity` measures how well given rotations explain the tracks as rigid over
every three consecutive frames; :func:`moju_core.cameras.estimate_cameras` uses it to choose
between estimates.
"""

from __future__ import annotations

import numpy as np

from moju_core.cameras.refinement import project_to_stiefel
from moju_core.cameras.rigid import rigid_from_factor

__all__ = [
    "RIGIDITY_WINDOW",
    "WINDOW_LENGTHS",
    "RowGram",
    "best_windowed_rotations",
    "short_time_rigidity",
    "windowed_rotations",
]

#: Window lengths (frames) tried by :func:`best_windowed_rotations`, besides the whole
#: sequence. Short windows see less deformation, long ones more camera motion; which wins
#: depends on the sequence, so a range is tried and the most rigid result kept.
WINDOW_LENGTHS = (6, 8, 10, 12, 15, 20, 25, 30, 40, 50)

#: Frames per window of the rigidity measure: the shortest window with more equations
#: (2 per frame) than a rigid point has unknowns (3).
RIGIDITY_WINDOW = 3


class RowGram:
    """Entries of ``W W^T`` between frames at most ``reach - 1`` apart.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Centred measurements.
    reach : int
        Longest window (in frames) whose Gram block will be asked for.
    """

    def __init__(self, W: np.ndarray, reach: int) -> None:
        n_rows = W.shape[0]
        self.n_frames = n_rows // 2
        self.reach = min(int(reach), self.n_frames)
        self.total = float(np.vdot(W, W))  # trace of W W^T
        self.dense: np.ndarray | None = None
        if self.reach >= self.n_frames // 2:
            self.dense = W @ W.T
            return
        # diagonals[k, i] = (W W^T)[i, i + k] for the 2 reach row offsets needed, zero-padded.
        width = 2 * self.reach
        self.diagonals = np.zeros((width, n_rows))
        for offset in range(width):
            self.diagonals[offset, : n_rows - offset] = np.einsum(
                "ip,ip->i", W[: n_rows - offset], W[offset:]
            )

    def windows(self, length: int) -> np.ndarray:
        """Gram blocks of every window of ``length`` consecutive frames.

        Returns
        -------
        ndarray of shape (F - length + 1, 2 length, 2 length)
            Entry ``[a]`` is ``W_a W_a^T`` for the rows ``2a .. 2(a + length) - 1``.
        """
        if not 1 <= length <= self.reach:
            raise ValueError(f"window length must be between 1 and {self.reach}, got {length}")
        n_windows = self.n_frames - length + 1
        starts = 2 * np.arange(n_windows)
        local = np.arange(2 * length)
        if self.dense is not None:
            rows = starts[:, None] + local
            return self.dense[rows[:, :, None], rows[:, None, :]]
        offsets = np.abs(local[:, None] - local[None, :])
        first = np.minimum(local[:, None], local[None, :])
        return self.diagonals[offsets[None], starts[:, None, None] + first[None]]


def _window_rotations(gram: RowGram, length: int) -> np.ndarray:
    """Tomasi-Kanade rotations of every window of ``length`` consecutive frames.

    Returns
    -------
    ndarray of shape (F - length + 1, length, 2, 3)
        Entry ``[a, i]`` is frame ``a + i`` as seen by window a.
    """
    blocks = gram.windows(length)  # (windows, 2L, 2L)
    eigenvalues, eigenvectors = np.linalg.eigh(blocks)
    # Motion factor U_3 S_3^(1/2) as in rigid_rotations (S: singular values, the square
    # roots of the Gram matrix's eigenvalues).
    weights = np.clip(eigenvalues[:, -3:], 0.0, None) ** 0.25
    return rigid_from_factor(eigenvectors[:, :, -3:] * weights[:, None, :])


def windowed_rotations(gram: RowGram, window: int) -> np.ndarray:
    """Rotations of every frame from rigid factorisations of overlapping windows.

    Parameters
    ----------
    gram : RowGram
        Blocks of ``W W^T`` of the centred tracks, reaching at least ``window`` frames.
    window : int
        Frames per window, ``3 <= window <= F``; ``window = F`` is the rigid method.

    Returns
    -------
    ndarray of shape (F, 2, 3)
        Rotations with orthonormal rows, up to one global rotation and reflection.
    """
    n_frames = gram.n_frames
    if not 3 <= window <= n_frames:
        raise ValueError(f"window must be between 3 and the number of frames {n_frames}")
    total = np.zeros((n_frames, 2, 3))
    count = np.zeros(n_frames)
    for start, rotations in enumerate(_window_rotations(gram, window)):
        if start > 0:
            # Align with the frames this window shares with the chain so far: the orthogonal
            # Q (reflections allowed, as the window's factorisation has them) minimising
            # ||A Q - B|| over their stacked rows.
            shared = slice(start, start + window - 1)
            A = rotations[:-1].reshape(-1, 3)
            B = (total[shared] / count[shared, None, None]).reshape(-1, 3)
            u, _, vt = np.linalg.svd(A.T @ B)
            rotations = rotations @ (u @ vt)
        total[start : start + window] += rotations
        count[start : start + window] += 1
    return project_to_stiefel(total / count[:, None, None])


def short_time_rigidity(gram: RowGram, rotations: np.ndarray) -> float:
    """Misfit of the tracks to a rigid shape over every three consecutive frames.

    For each window of ``RIGIDITY_WINDOW`` frames with stacked rotations ``R_w`` (6 x 3) the
    best rigid shape leaves ``tr(G_w) - tr(P_w G_w)`` of the window's energy ``tr(G_w)``
    unexplained, ``P_w`` the projector onto the columns of ``R_w`` and ``G_w`` the window's
    block of ``W W^T``. Correct rotations leave only the deformation within three frames
    (and noise); wrong ones add apparent deformation. White noise of variance sigma^2 per
    entry adds about ``sigma^2 / 2`` of every entry's energy (3 unknowns for 6 equations).

    Parameters
    ----------
    gram : RowGram
        Blocks of ``W W^T`` of the centred tracks.
    rotations : ndarray of shape (F, 2, 3)

    Returns
    -------
    float
        Unexplained energy over the energy of all windows, in [0, 1].
    """
    n_frames = rotations.shape[0]
    window = min(RIGIDITY_WINDOW, n_frames)
    n_windows = n_frames - window + 1
    blocks = gram.windows(window)  # (windows, 2w, 2w)
    stacked = rotations[np.arange(n_windows)[:, None] + np.arange(window)]
    stacked = stacked.reshape(n_windows, 2 * window, 3)
    # Orthonormal bases of the columns of R_w (rank 2 if the camera did not turn: the
    # direction of the smallest singular value is then dropped).
    basis, singular, _ = np.linalg.svd(stacked, full_matrices=False)
    basis = basis * (singular > 1e-9 * singular[:, :1])[:, None, :]
    explained = np.einsum("wik,wij,wjk->", basis, blocks, basis)
    energy = float(np.trace(blocks, axis1=1, axis2=2).sum())
    return float(max(energy - explained, 0.0) / energy) if energy > 0 else 0.0


def best_windowed_rotations(gram: RowGram, rigid: np.ndarray) -> tuple[np.ndarray, int, float]:
    """The windowed rotations of the window length that is most rigid over three frames.

    Tries every length of :data:`WINDOW_LENGTHS` shorter than the sequence, and the whole
    sequence (the rigid estimate), and keeps the one with the smallest
    :func:`short_time_rigidity`.

    Parameters
    ----------
    gram : RowGram
        Blocks of ``W W^T`` of the centred tracks (F >= 3), reaching
        ``max(WINDOW_LENGTHS)`` frames.
    rigid : ndarray of shape (F, 2, 3)
        Tomasi-Kanade rotations of the whole sequence
        (:func:`moju_core.cameras.rigid.rigid_rotations`).

    Returns
    -------
    rotations : ndarray of shape (F, 2, 3)
    window : int
        The chosen window length (F for the rigid estimate).
    rigidity : float
        Its :func:`short_time_rigidity`.
    """
    n_frames = gram.n_frames
    candidates = [
        (windowed_rotations(gram, length), length) for length in WINDOW_LENGTHS if length < n_frames
    ] + [(rigid, n_frames)]
    best: tuple[np.ndarray, int, float] | None = None
    for rotations, length in candidates:
        rigidity = short_time_rigidity(gram, rotations)
        if best is None or rigidity < best[2]:
            best = (rotations, length, rigidity)
    assert best is not None
    return best
