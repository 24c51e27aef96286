"""The neighbour check: positions that leave their neighbours' affine motion."""

import numpy as np
from numpy.testing import assert_array_equal

from moju_core.neighbour_check import (
    TOLERANCE_PX,
    departures,
    explained,
    neighbour_residuals,
    trusted,
)


def grid_tracks(n_frames: int = 8, side: int = 20, noise: float = 0.05, seed: int = 0):
    """W (2F, P) and visibility of a 20 x 20 grid (4 px step) under a smooth perspective-like
    motion (rotation, zoom and a gentle quadratic warp), with Gaussian noise (px)."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(side) * 4.0, np.arange(side) * 4.0)
    start = np.stack([x.ravel(), y.ravel()], axis=1) + 100.0
    frames = []
    for f in range(n_frames):
        angle, zoom = 0.01 * f, 1.0 + 0.01 * f
        rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        centred = start - 140.0
        warp = 1e-4 * f * centred**2  # smooth, not affine
        frames.append(zoom * centred @ rotation.T + warp + 140.0 + [2.0 * f, f])
    positions = np.stack(frames) + rng.normal(0.0, noise, (n_frames,) + start.shape)
    positions[0] = start
    W = positions.transpose(0, 2, 1).reshape(2 * n_frames, -1)
    return W, np.ones((n_frames, start.shape[0]), dtype=bool)


def drift(W: np.ndarray, points, from_frame: int, px_per_frame: float) -> np.ndarray:
    """W with ``points`` sliding right by ``px_per_frame`` per frame from ``from_frame`` on."""
    W = W.copy()
    n_frames = W.shape[0] // 2
    for f in range(from_frame, n_frames):
        W[2 * f, points] += px_per_frame * (f - from_frame + 1)
    return W


def test_a_smooth_motion_with_noise_has_no_departure():
    W, visibility = grid_tracks()
    residual, typical = neighbour_residuals(W, visibility)
    assert np.all(residual[0] == 0.0) and np.all(typical[0] == 0.0)
    assert np.nanmax(residual) < 0.5 and np.nanmax(typical) < 0.5
    assert not departures(W, visibility).any()


def test_a_drifting_track_is_lost_where_it_has_drifted_only():
    W, visibility = grid_tracks()
    point = 210  # inside the grid
    lost = departures(drift(W, [point], from_frame=3, px_per_frame=0.6), visibility)
    # 0.6, 1.2, 1.8, ... px off from frame 3 on: a departure once more than 0.89 px off
    assert np.flatnonzero(lost[:, point]).tolist() == [4, 5, 6, 7]
    lost[:, point] = False
    assert not lost.any()  # its neighbours keep every frame


def test_neighbours_that_drift_together_are_still_caught():
    """Three adjacent tracks drifting together: the robust fit follows the other neighbours."""
    W, visibility = grid_tracks()
    group = [210, 211, 230]
    lost = departures(drift(W, group, from_frame=2, px_per_frame=1.5), visibility)
    assert lost[2:, group].all()
    assert not np.delete(lost, group, axis=1).any()


def test_hidden_entries_and_thin_frames_are_not_judged():
    W, visibility = grid_tracks(n_frames=4)
    visibility[1, :] = False
    visibility[1, :4] = True  # 4 seen points: too few neighbours for a map with one to spare
    visibility[2, 7] = False
    W[np.repeat(~visibility, 2, axis=0)] = np.nan
    residual, typical = neighbour_residuals(W, visibility)
    assert np.isnan(residual[1]).all() and np.isnan(typical[1]).all()
    assert np.isnan(residual[2, 7]) and np.isfinite(np.delete(residual[2], 7)).all()
    assert not departures(W, visibility).any()


def test_parts_that_move_apart_lose_only_their_edges_and_only_at_first():
    """The right half of the grid moves away from the left half by 10 px a frame. Near the
    gap a patch mixes the two motions until the parts are about a patch apart (the neighbours
    are those near in both frames, so none come from across a wide gap): a departure there,
    in the first two frames only; nowhere else."""
    W, visibility = grid_tracks(n_frames=6, noise=0.02)
    x0 = W[0].copy()
    right = x0 >= x0.min() + 40.0
    for f in range(6):
        W[2 * f, right] += 10.0 * f
    lost = departures(W, visibility)
    assert not lost[3:].any()
    assert np.all(np.abs(x0[lost.any(axis=0)] - (x0.min() + 38.0)) <= 6.0)


def test_a_track_is_judged_from_the_first_frame_that_sees_it():
    W, visibility = grid_tracks()
    late = [150, 151]
    visibility[:2, late] = False
    W[np.repeat(~visibility, 2, axis=0)] = np.nan
    residual, _ = neighbour_residuals(W, visibility)
    assert np.isnan(residual[:2, late]).all() and np.all(residual[2, late] == 0.0)
    assert np.nanmax(residual[3:, late]) < 0.5
    lost = departures(drift(W, late, from_frame=4, px_per_frame=2.0), visibility)
    assert lost[4:, late].all() and not lost[:4].any()


def test_trusted_keeps_the_solvers_minimums():
    W, visibility = grid_tracks(n_frames=4)
    W = drift(W, [210], from_frame=1, px_per_frame=2.0)  # off in frames 1-3
    W = drift(W, [190], from_frame=3, px_per_frame=2.0)  # off in frame 3
    assert departures(W, visibility)[1:, 210].all() and departures(W, visibility)[3, 190]
    kept = trusted(W, visibility)
    assert kept[:, 210].all()  # hiding frames 1-3 would leave it seen once: kept whole
    assert not kept[3, 190] and kept[:3, 190].all()
    assert kept.sum() == visibility.sum() - 1
    assert_array_equal(trusted(*grid_tracks()), grid_tracks()[1])  # nothing to set aside


def test_tracks_the_affine_motion_does_not_explain_are_not_judged():
    """Points with no local motion to follow (random positions in every frame, as sparse
    points of views far apart): nothing is a departure."""
    rng = np.random.default_rng(1)
    W, visibility = rng.uniform(0, 100, (10, 30)), np.ones((5, 30), dtype=bool)
    residual, _ = neighbour_residuals(W, visibility)
    assert np.nanmedian(residual[1:]) > 5.0 and not explained(np.nan_to_num(residual))
    assert not departures(W, visibility).any()
    assert_array_equal(trusted(W, visibility), visibility)


def test_a_fold_is_not_taken_for_drift():
    """The right half folds about the column x = 140 (its image shrinks by 10 % a frame): the
    motion is not affine across the fold, and the neighbours' own misfit says so. Only the
    fold's own column can be set aside; the distance alone would set aside many more."""
    W, visibility = grid_tracks(n_frames=6, noise=0.02)
    x0 = W[0].copy()
    for f in range(6):
        W[2 * f] = np.where(x0 > 140.0, 140.0 + (x0 - 140.0) * (1 - 0.1 * f), x0) + 2.0 * f
    lost = departures(W, visibility)
    assert np.all(x0[lost.any(axis=0)] == 140.0)
    residual, _ = neighbour_residuals(W, visibility)
    assert (np.nan_to_num(residual) > TOLERANCE_PX).sum() > 5 * lost.sum()
