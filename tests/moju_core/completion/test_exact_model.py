"""When a completion counts as exact: the thresholds of moju_core.completion.exact_model.

An exact model fits its hidden entries as data, so it must be refused for tracks that are
low-rank only to within some small deviation (``EXACT_FIT_MISFIT``), and for a model whose
prediction of held-out entries misses (``EXACT_MODEL_ERROR``); and the spare directions of an
exact fit are cut using only the points that see every direction (``VISIBLE_DIRECTIONS``).
Each test below fails with its threshold moved as docs/constants.md records.
"""

from __future__ import annotations

import numpy as np
import pytest

from moju_core.completion import exact_model
from moju_core.datasets import make_sequence, occlusion_mask


def _low_rank_w(rng, n_rows=120, n_points=400, rank=5):
    """Tracks of rank ``rank`` plus a translation (uncentred rank ``rank + 1``)."""
    left = rng.standard_normal((n_rows, rank))
    right = rng.standard_normal((rank, n_points))
    return left @ right + rng.standard_normal(n_rows)[:, None] * 5.0


def _band_visibility(n_frames=60, n_points=400, seed=0):
    """A face's occlusion: a sweeping band, lost tracks and dropped entries."""
    face = make_sequence("face3", n_points=n_points, n_frames=n_frames, seed=seed)
    return occlusion_mask(face, band=0.2, lost=0.1, dropout=0.02, seed=seed)


def test_tracks_a_millionth_of_their_rms_off_a_low_rank_model_are_not_fitted_exactly():
    """Alternating least squares fits noise-free tracks to rounding (a misfit of 1e-17 of
    the entries' mean square) and counts that as exact; tracks off the model by 1e-6 of
    their RMS leave a misfit of 1e-12 that no sweep removes, and get no exact model."""
    rng = np.random.default_rng(22)
    visibility = _band_visibility()
    W = _low_rank_w(rng)
    start = np.linalg.svd(W, full_matrices=False)[0][:, :6] + 0.3 * rng.standard_normal((120, 6))
    off = W + 1e-6 * np.sqrt(np.mean(W**2)) * rng.standard_normal(W.shape)
    patience = exact_model.EXACT_PATIENCE
    assert exact_model._alternate(W, visibility, start, patience) is not None
    assert exact_model._alternate(off, visibility, start, patience) is None
    assert exact_model.exact_model(W, visibility) is not None
    assert exact_model.exact_model(off, visibility) is None


def test_a_deformation_of_one_frame_leaves_hidden_entries_undetermined_and_no_exact_model():
    """The observed entries are fitted exactly with one direction for the frame's jolt, but
    a point hidden in that frame has nothing to fix its share of it: the test points'
    held-out entries of that frame are missed, and the model is refused."""
    rng = np.random.default_rng(21)
    visibility = _band_visibility()
    W = _low_rank_w(rng)
    jolt = np.zeros(120)
    jolt[20:22] = rng.standard_normal(2)  # frame 10 only
    W += 1e-5 * np.sqrt(np.mean(W**2)) * np.outer(jolt, rng.standard_normal(400))
    assert exact_model.exact_model(W, visibility) is None


@pytest.mark.parametrize("seed", [0, 2])
def test_noise_free_faces_under_occlusion_get_an_exact_model(seed):
    """Held-out entries of an exactly low-rank face are predicted to 1e-13 to 1e-12 of its
    mean square: the threshold must leave them exact."""
    face = make_sequence("face3", n_points=600, n_frames=60, seed=seed)
    visibility = occlusion_mask(face, band=0.2, lost=0.1, dropout=0.02, seed=seed)
    model = exact_model.exact_model(face.W, visibility)
    assert model is not None and model.exact


def test_points_that_see_spare_directions_only_at_rounding_level_do_not_set_the_cut():
    """Spare directions of an exact fit seen by 80 points at 1e-6 only (the level measured
    on faces): their coefficients there are set by the ridge, not by the data, and would
    make the spare directions look like W's own; the cut uses the other points."""
    rng = np.random.default_rng(15)
    W = _low_rank_w(rng)  # uncentred rank 6
    visibility = rng.random((60, 400)) > 0.02
    visibility[10:20, :80] = False  # 80 points hidden in frames 10-19
    spare = 1e-6 * rng.standard_normal((120, 2))
    spare[20:40] = rng.standard_normal((20, 2))
    left = np.hstack([np.linalg.svd(W, full_matrices=False)[0][:, :6], spare])
    left = left @ rng.standard_normal((8, 8))
    trimmed = exact_model._trimmed(W, visibility, left, 6)
    assert trimmed.shape[1] == 6
    cosines = np.linalg.svd(
        np.linalg.svd(W, full_matrices=False)[0][:, :6].T @ np.linalg.qr(trimmed)[0],
        compute_uv=False,
    )
    assert cosines.min() > 1 - 1e-10
