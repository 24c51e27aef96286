"""The neighbour check: positions that leave their neighbours' affine motion."""

import numpy as np

from moju_core.footage.neighbour_check import departures, neighbour_residuals

TOLERANCE = 0.9


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
    residual = neighbour_residuals(W, visibility)
    assert np.all(residual[0] == 0.0)
    assert np.nanmax(residual) < 0.5
    assert not departures(W, visibility, TOLERANCE).any()


def test_a_drifting_track_is_lost_where_it_has_drifted_only():
    W, visibility = grid_tracks()
    point = 210  # inside the grid
    lost = departures(drift(W, [point], from_frame=3, px_per_frame=0.6), visibility, TOLERANCE)
    # 0.6, 1.2, 1.8, ... px off from frame 3 on: lost where it is 0.9 px + the fit's spread off
    assert np.flatnonzero(lost[:, point]).tolist() == [4, 5, 6, 7]
    lost[:, point] = False
    assert not lost.any()  # its neighbours keep every frame


def test_neighbours_that_drift_together_are_still_caught():
    """Three adjacent tracks drifting together: the robust fit follows the other neighbours."""
    W, visibility = grid_tracks()
    group = [210, 211, 230]
    lost = departures(drift(W, group, from_frame=2, px_per_frame=1.5), visibility, TOLERANCE)
    assert lost[2:, group].all()
    assert not np.delete(lost, group, axis=1).any()


def test_hidden_entries_and_thin_frames_are_not_judged():
    W, visibility = grid_tracks(n_frames=4)
    visibility[1, :] = False
    visibility[1, :4] = True  # 4 seen points: too few neighbours for a map with one to spare
    visibility[2, 7] = False
    W[np.repeat(~visibility, 2, axis=0)] = np.nan
    residual = neighbour_residuals(W, visibility)
    assert np.isnan(residual[1]).all()
    assert np.isnan(residual[2, 7]) and np.isfinite(np.delete(residual[2], 7)).all()
    assert not departures(W, visibility, TOLERANCE).any()
