"""Block sizes of the completion bound memory only: any block gives the same numbers."""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose

from moju_core.completion import missing, neighbours
from moju_core.datasets import make_sequence, occlusion_mask


def test_the_prediction_variance_does_not_depend_on_its_block_size(monkeypatch):
    """``missing.VARIANCE_BLOCK``: a block of one normal matrix at a time against all at once."""
    rng = np.random.default_rng(0)
    features = rng.standard_normal((50, 4))
    normals = np.einsum("mia,mib->mab", *(2 * [rng.standard_normal((30, 12, 4))]))
    whole, base = missing._variance(features, normals)
    monkeypatch.setattr(missing, "VARIANCE_BLOCK", 1)
    blocked, blocked_base = missing._variance(features, normals)
    assert_allclose(blocked, whole, rtol=1e-13, atol=0)
    assert np.array_equal(blocked_base, base)


def test_the_neighbour_values_do_not_depend_on_their_block_size(monkeypatch):
    """``neighbours._BLOCK_ENTRIES``: one point per block against all points at once."""
    data = make_sequence("face3", n_points=200, n_frames=30, seed=0)
    visibility = occlusion_mask(data, band=0.0, lost=0.15, dropout=0.0, seed=0)
    hidden = np.where(missing.expand_mask(visibility), data.W, 0.0)
    model = missing.complete_at_rank(hidden, visibility, 6)
    reliable = missing.trusted_entries(model, visibility)
    values, borrowed = neighbours.borrow_values(model, hidden, visibility, reliable)
    assert borrowed.any()
    monkeypatch.setattr(neighbours, "_BLOCK_ENTRIES", 1)
    blocked, blocked_borrowed = neighbours.borrow_values(model, hidden, visibility, reliable)
    assert np.array_equal(blocked_borrowed, borrowed)
    assert_allclose(blocked, values, rtol=1e-12, atol=1e-12 * np.abs(values).max())
