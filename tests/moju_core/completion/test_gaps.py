import numpy as np
import pytest

from moju_core.completion import gaps, missing
from moju_core.datasets import make_sequence, occlusion_mask
from moju_core.validation import with_missing


def test_the_nearest_observed_frames_of_each_entry():
    visibility = np.array([[False], [True], [False], [False], [True], [False]])
    previous, following = gaps.nearest_observed(visibility)
    assert previous[:, 0].tolist() == [-1, 1, 1, 1, 4, 4]
    assert following[:, 0].tolist() == [1, 1, 4, 4, 4, 6]


def test_inside_a_gap_the_track_or_the_residual_is_interpolated_beyond_the_ends_the_residual():
    visibility = np.array([[False], [True], [False], [False], [True], [False]])
    W = np.zeros((12, 1))
    W[2:4, 0] = [3.0, -3.0]  # frame 1 (x, y)
    W[8:10, 0] = [6.0, 0.0]  # frame 4
    values = np.full((12, 1), 1.0)
    values[8] = 2.0  # the completion at frame 4 (x)
    tracks = gaps.correction(W, values, visibility, gaps.GapFill(track=np.inf))
    residual = gaps.correction(W, values, visibility, gaps.GapFill(residual=np.inf))
    tracks, residual = tracks.reshape(6, 2), residual.reshape(6, 2)
    # Frames 2 and 3: the track (3 -> 6) less the completion (1), or the residual (2 -> 4).
    assert np.allclose(tracks[:, 0], [0.0, 0.0, 3.0, 4.0, 0.0, 0.0])
    assert np.allclose(residual[:, 0], [2.0, 0.0, 2.0 + 2.0 / 3.0, 2.0 + 4.0 / 3.0, 0.0, 4.0])
    # y: the track (-3 -> 0) less 1 is the residual (-4 -> -1) interpolated.
    assert np.allclose(residual[:, 1], [-4.0, 0.0, -3.0, -2.0, 0.0, -1.0])
    assert np.allclose(tracks[2:4, 1], residual[2:4, 1])
    both = gaps.GapFill(track=np.inf, residual=np.inf)
    both = gaps.correction(W, values, visibility, both).reshape(6, 2)
    assert np.allclose(both[:, 0], [2.0, 0.0, 3.0, 4.0, 0.0, 4.0])


def test_the_correction_decays_with_the_distance_to_the_nearer_observed_frame():
    visibility = np.zeros((8, 1), dtype=bool)
    visibility[0] = True
    W = np.zeros((16, 1))
    W[0] = 1.0
    values = np.zeros((16, 1))
    out = gaps.correction(W, values, visibility, gaps.GapFill(residual=2.0))
    out = out.reshape(8, 2)[:, 0]
    assert np.allclose(out[1:], np.exp(-np.arange(1, 8) / 2.0))
    assert not gaps.correction(W, values, visibility, gaps.GapFill()).any()


def test_the_distance_to_the_nearest_observed_frame():
    visibility = np.array([[False, False], [True, False], [False, False], [False, False]])
    assert gaps.distance_to_observed(visibility)[:, 0].tolist() == [1, 0, 1, 2]
    assert np.all(gaps.distance_to_observed(visibility)[:, 1] > 4)


def test_a_point_seen_in_no_frame_gets_no_correction():
    visibility = np.array([[True, False], [False, False]])
    for gap in gaps.CANDIDATES:
        out = gaps.correction(np.ones((4, 2)), np.zeros((4, 2)), visibility, gap)
        assert np.all(np.isfinite(out))
        assert not out[:, 1].any()


def test_filled_keeps_the_measurements_and_ignores_the_hidden_values():
    rng = np.random.default_rng(0)
    visibility = rng.random((20, 5)) > 0.3
    W = rng.standard_normal((40, 5))
    values = rng.standard_normal((40, 5))
    gap = gaps.GapFill(track=3.0, residual=10.0)
    out = gaps.filled(values, W, visibility, gap)
    mask = np.repeat(visibility, 2, axis=0)
    assert np.array_equal(out[mask], W[mask])
    changed = W.copy()
    changed[~mask] = 1e6
    assert np.array_equal(gaps.filled(values, changed, visibility, gap), out)


def _body(noise: float, seed: int):
    data = make_sequence("body-osc", n_points=41, n_frames=350, seed=seed, noise=noise)
    visibility = occlusion_mask(data, band=0.0, lost=0.0, dropout=0.1, seed=seed)
    W = np.nan_to_num(with_missing(data.W, visibility))
    return data, visibility, W


def _hidden_error(data, visibility, filled) -> float:
    hidden = ~np.repeat(visibility, 2, axis=0)
    return float(np.sqrt(np.mean((filled - data.W)[hidden] ** 2)))


def test_noise_free_markers_with_short_gaps_are_filled_from_their_own_tracks():
    # An articulated body is not of low rank: the completion misses at the hidden entries what
    # the track's neighbouring frames show.
    data, visibility, W = _body(0.0, 1)
    model = missing.complete(W, visibility)
    assert model.gap.corrects
    completion = np.where(np.repeat(visibility, 2, axis=0), W, model.values())
    plain = _hidden_error(data, visibility, completion)
    corrected = _hidden_error(data, visibility, model.fill(W, visibility))
    assert corrected < 0.6 * plain


@pytest.mark.parametrize("seed", [1, 2])
def test_noisy_tracks_of_a_low_rank_face_choose_little_or_no_correction(seed):
    # At 1 % noise the residual at a neighbouring frame is mostly noise.
    data = make_sequence("face3", n_points=300, seed=seed, noise=0.01)
    visibility = occlusion_mask(data, band=0.0, lost=0.0, dropout=0.1, seed=seed)
    W = np.nan_to_num(with_missing(data.W, visibility))
    model = missing.complete(W, visibility, noise=missing.observed_noise_variance(W, visibility))
    assert model.gap.track <= 1.0 and model.gap.residual <= 1.0


def test_the_pieces_at_some_entries_give_the_correction_there():
    rng = np.random.default_rng(3)
    visibility = rng.random((30, 8)) > 0.4
    W, values = rng.standard_normal((60, 8)), rng.standard_normal((60, 8))
    parts = gaps.pieces(W, values, visibility)
    mask = rng.random((60, 8)) > 0.5
    for gap in gaps.CANDIDATES:
        full = gaps.correction(W, values, visibility, gap)
        assert np.allclose(parts.at(mask).correction(gap), full[mask])
        assert not full[np.repeat(visibility, 2, axis=0)].any()
