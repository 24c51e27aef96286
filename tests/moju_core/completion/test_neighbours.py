from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from moju_core.completion import missing, neighbours
from moju_core.datasets import make_sequence, occlusion_mask


def _borrow(W, visibility, rank=None):
    hidden = np.where(missing.expand_mask(visibility), W, 0.0)
    if rank is None:
        model = missing.complete(hidden, visibility)
    else:
        model = missing.complete_at_rank(hidden, visibility, rank)
    reliable = missing.trusted_entries(model, visibility)
    return model, reliable, *neighbours.borrow_values(model, hidden, visibility, reliable)


def _rms(error, mask):
    return float(np.sqrt(np.mean(error[missing.expand_mask(mask)] ** 2)))


def test_tracks_lost_early_are_predicted_from_their_neighbours_far_better_than_alone():
    data = make_sequence("face3", n_points=800, n_frames=60, seed=0)
    visibility = occlusion_mask(data, band=0.0, lost=0.15, dropout=0.0, seed=0)
    model, reliable, values, borrowed = _borrow(data.W, visibility)
    assert borrowed.any()
    assert_array_equal(borrowed, ~reliable.all(axis=0) & ~missing.well_seen(visibility))
    hidden = ~visibility & borrowed[None, :]
    alone = _rms(model.values() - data.W, hidden)
    together = _rms(values - data.W, hidden)
    assert together < 0.2 * alone
    # The points whose entries are all reliable keep the model's values.
    kept = reliable.all(axis=0)
    assert kept.any()
    assert_array_equal(values[:, kept], model.values()[:, kept])


def _two_sheets(n_frames=12, side=12):
    """A sliding sheet and a static sheet, seen from the front, that coincide in the image in
    frame 0: (2F, 2 side^2), the sliding sheet's points first; rank 3 with the translation."""
    grid = np.stack(np.meshgrid(np.linspace(0, 1, side), np.linspace(0, 1, side)), 0)
    grid = grid.reshape(2, -1)
    rows = []
    for f in range(n_frames):
        shift = [[0.1 * f], [0.05 * f]]
        rows.append(np.hstack([grid + np.array(shift), grid]))
    return np.vstack(rows)


def test_neighbours_come_from_the_points_trajectory_not_from_one_frame_where_surfaces_overlap():
    W = _two_sheets()
    n_frames, n_points = W.shape[0] // 2, W.shape[1]
    visibility = np.ones((n_frames, n_points), dtype=bool)
    lost = np.arange(n_points // 2, n_points, 7)  # points of the static sheet, lost after frame 3
    visibility[4:, lost] = False
    hidden = np.where(missing.expand_mask(visibility), W, 0.0)
    model = missing.complete_at_rank(hidden, visibility, 3)
    values, borrowed = neighbours.borrow_values(model, W, visibility, reliable=visibility)
    assert_array_equal(borrowed, np.isin(np.arange(n_points), lost))
    # The static sheet's points stay where they were; the nearest points in frame 0 are
    # those of the sliding sheet, which would carry them along.
    assert_allclose(values[:, lost], W[:, lost], atol=5e-3)


def test_an_affine_combination_of_the_neighbours_reproduces_a_point_of_a_rigid_plane():
    rng = np.random.default_rng(1)
    n_frames, n_points = 30, 400
    plane = np.vstack([rng.uniform(-1, 1, (2, n_points)), np.zeros((1, n_points))])
    angles = np.linspace(0, 1.2, n_frames)
    W = np.vstack(
        [
            np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0]]) @ plane
            + np.array([[0.1 * a], [-0.2 * a]])
            for a in angles
        ]
    )
    visibility = np.ones((n_frames, n_points), dtype=bool)
    visibility[3:, :20] = False  # 20 points seen in the first three frames only
    model, reliable, values, borrowed = _borrow(W, visibility, rank=2)
    assert borrowed[:20].all()
    assert_allclose(values[:, :20], W[:, :20], atol=5e-3)


def test_a_well_seen_point_keeps_its_reliable_values_and_takes_its_neighbours_elsewhere():
    data = make_sequence("face1", n_points=200, seed=0)
    visibility = occlusion_mask(data, band=0.0, lost=0.0, dropout=0.05, seed=0)
    hidden = np.where(missing.expand_mask(visibility), data.W, 0.0)
    model = missing.complete(hidden, visibility)
    reliable = np.ones_like(visibility)
    reliable[-1, :10] = visibility[-1, :10] = False  # points 0-9 hidden, unreliable at the end
    reliable[2:, 10:15] = visibility[2:, 10:15] = False  # points 10-14 seen in two frames only
    values, borrowed = neighbours.borrow_values(model, hidden, visibility, reliable)
    assert_array_equal(np.flatnonzero(borrowed), np.arange(10, 15))
    expected = model.values()
    changed = values != expected
    rows = missing.expand_mask(~reliable)
    assert changed[:, :10].any(axis=0).all()
    assert_array_equal(changed[:, :10], rows[:, :10])
    assert not changed[:, 15:].any()


def test_a_well_seen_points_unreliable_entries_come_from_neighbours_reliable_there():
    # A sparse face under a band: the model's values at the band's unreliable entries are off; the
    # neighbours' combination is much closer to the truth there.
    data = make_sequence("face4", n_points=41, n_frames=350, seed=1)
    visibility = occlusion_mask(data, band=0.2, lost=0.1, dropout=0.02, seed=1)
    model, reliable, values, borrowed = _borrow(data.W, visibility)
    partial = missing.well_seen(visibility)[None, :] & ~reliable
    assert partial.any()
    alone = _rms(model.values() - data.W, partial)
    together = _rms(values - data.W, partial)
    assert together < 0.1 * alone


@pytest.mark.parametrize("lost", [0.0, 0.05])
def test_no_point_is_borrowed_when_every_entry_is_reliable_or_no_point_is_well_seen(lost):
    data = make_sequence("face1", n_points=200, seed=0)
    visibility = occlusion_mask(data, band=0.0, lost=lost, dropout=0.05, seed=0)
    model, reliable, values, borrowed = _borrow(data.W, visibility)
    expected = ~reliable.all(axis=0) & ~missing.well_seen(visibility)
    assert_array_equal(borrowed, expected)
    if lost == 0.0:
        assert not borrowed.any()
        assert_array_equal(values, model.values())
    seen_twice = np.zeros_like(visibility)
    seen_twice[:2] = True
    same, nothing = neighbours.borrow_values(model, data.W, seen_twice, seen_twice)
    assert_array_equal(same, model.values())
    assert not nothing.any()


def test_the_weights_of_noisy_tracks_seen_in_a_few_frames_do_not_fit_their_noise():
    # Points that are affine combinations of 8 neighbours in every frame, seen with noise in
    # 3 frames: without the noise in the ridge their weights reproduce the noise there and
    # carry it, amplified, into the other 37.
    rng = np.random.default_rng(0)
    n_frames, n_points, k = 40, 200, 8
    neighbour_tracks = rng.standard_normal((2 * n_frames, n_points, k)).cumsum(axis=0) * 0.1
    true_weights = rng.dirichlet(np.ones(k), size=n_points)
    clean = np.einsum("rnk,nk->rn", neighbour_tracks, true_weights)
    sigma = 0.05
    tracks = clean + sigma * rng.standard_normal(clean.shape)
    rows = np.zeros_like(clean, dtype=bool)
    rows[:6] = True  # frames 0-2
    values = neighbour_tracks.reshape(2 * n_frames, n_points * k)
    errors = {}
    for noise in (0.0, sigma**2):
        weights = neighbours._affine_weights(values, tracks * rows, rows, k, noise)
        combined = np.einsum("rnk,nk->rn", neighbour_tracks, weights)
        errors[noise] = float(np.sqrt(np.mean((combined - clean)[~rows] ** 2)))
    assert errors[sigma**2] < 0.5 * errors[0.0]


def test_an_entry_whose_neighbours_are_unreliable_there_too_takes_its_track_interpolated():
    # The left 60 % of a grid are hidden in frame 5 and the model is off there (a shifted
    # row): the far-left points have no reliable neighbour in that frame.
    n_frames, side = 12, 10
    x, y = (g.ravel() for g in np.meshgrid(np.linspace(0, 1, side), np.linspace(0, 1, side)))
    f = np.arange(n_frames)[:, None]
    W = np.stack([x + 0.1 * f + 0.2 * np.sin(f) * y, y - 0.05 * f + 0.1 * np.cos(f) * x], axis=1)
    W = W.reshape(2 * n_frames, x.size)
    visibility = np.ones((n_frames, x.size), dtype=bool)
    visibility[5, x < 0.6] = False
    hidden = np.where(missing.expand_mask(visibility), W, 0.0)
    model = missing.complete_at_rank(hidden, visibility, 3)
    shifted = model.translation.copy()
    shifted[10:12] += 5.0
    model = replace(model, translation=shifted)
    values, borrowed = neighbours.borrow_values(model, hidden, visibility, reliable=visibility)
    assert not borrowed.any()
    far_left = np.flatnonzero(x == 0.0)
    interpolated = 0.5 * (W[8:10, far_left] + W[12:14, far_left])
    assert_allclose(values[10:12, far_left], interpolated, atol=1e-12)
