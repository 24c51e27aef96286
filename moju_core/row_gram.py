"""The blocks of the row Gram matrix ``W W^T`` near its diagonal, without forming all of it.

The windowed camera estimate (:mod:`moju_core.windowed_rotations`) needs only the Gram
matrices of windows of consecutive frames, i.e. the entries of ``W W^T`` (2F x 2F) between
rows at most ``2 reach`` apart. For short sequences the whole product is cheaper and is
formed; for long ones (motion capture: thousands of frames of tens of markers) the
``2 (2 reach) + 1`` diagonals are computed one by one, O(F P reach) time and O(F reach)
memory instead of O(F^2 P) and O(F^2).
"""

from __future__ import annotations

import numpy as np


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
