"""Blocks of W W^T near the diagonal, formed densely or from its diagonals."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from moju_core.row_gram import RowGram


@pytest.mark.parametrize(("n_frames", "reach"), [(40, 6), (40, 30), (9, 9)])
def test_window_blocks_are_the_blocks_of_the_full_product(n_frames, reach):
    W = np.random.default_rng(n_frames).standard_normal((2 * n_frames, 7))
    gram = RowGram(W, reach)
    assert (gram.dense is None) == (reach < n_frames // 2)
    full = W @ W.T
    for length in (1, 3, reach):
        blocks = gram.windows(length)
        assert blocks.shape == (n_frames - length + 1, 2 * length, 2 * length)
        for start in (0, n_frames - length):
            rows = slice(2 * start, 2 * (start + length))
            assert_allclose(blocks[start], full[rows, rows], atol=1e-12)
    assert gram.total == pytest.approx(np.trace(full))
    with pytest.raises(ValueError, match="window length"):
        gram.windows(reach + 1)
