"""The loop's state: the zero-depth start, the joint re-permutation of its point arrays."""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_array_equal

from moju_core.cameras import projection as camera
from moju_core.datasets import make_sequence
from moju_core.loop.loop_state import group_bounds, initial_state, permute_points


def _state(observed: bool = False, seed: int = 0):
    data = make_sequence("face1", n_frames=6, n_points=40, seed=seed)
    tracks = data.W.reshape(data.n_frames, 2, data.n_points)
    tracks = tracks - tracks.mean(axis=2, keepdims=True)
    mask = None
    if observed:
        mask = np.random.default_rng(seed).random((data.n_frames, data.n_points)) > 0.2
    return initial_state(tracks, data.rotations, 0.01, mask), tracks, data.rotations, mask


def test_the_start_has_zero_depth_and_reprojects_the_tracks() -> None:
    state, tracks, rotations, _ = _state()
    assert_array_equal(state.sharp, state.shape_form)  # S# = f(S)
    assert not np.shares_memory(state.sharp, state.shapes)
    assert np.allclose(camera.project(rotations, state.shapes), tracks)
    depth = np.einsum("fc,fcp->fp", state.normals, state.shapes)
    assert np.allclose(depth, 0.0)
    assert not state.scaled.any()
    assert state.n_groups == 1 and list(state.bounds) == [0, state.n_points]


def test_unobserved_entries_are_zero_in_the_tracks_but_start_from_the_completion() -> None:
    state, tracks, rotations, mask = _state(observed=True)
    hidden = ~mask
    assert not state.tracks[:, 0][hidden].any() and not state.tracks[:, 1][hidden].any()
    assert np.allclose(camera.project(rotations, state.shapes), tracks)  # all entries


def test_the_trajectory_and_shape_forms_are_views_of_the_shapes() -> None:
    state, *_ = _state()
    state.trajectories[4, 7] = 123.0  # row 3f + c: frame 1, coordinate 1
    assert state.shapes[1, 1, 7] == 123.0
    state.shape_form[2, 2 * state.n_points + 5] = -5.0  # row f, column c P + j
    assert state.shapes[2, 2, 5] == -5.0


def test_permute_moves_every_point_array_together_and_can_be_undone() -> None:
    state, *_ = _state(observed=True)
    n_points = state.n_points
    rng = np.random.default_rng(1)
    state.labels = rng.integers(0, 3, n_points)
    state.n_groups = 3
    state.features = rng.standard_normal((n_points, 2))
    state.scaled = rng.standard_normal(state.scaled.shape)
    before = {
        name: getattr(state, name).copy()
        for name in ("shapes", "sharp", "scaled", "tracks", "observed", "back_projected")
    }
    features, labels = state.features.copy(), state.labels.copy()
    perm = np.argsort(state.labels, kind="stable")
    state.permute(perm)

    assert_array_equal(state.order, perm)
    assert np.all(np.diff(state.labels) >= 0)
    assert_array_equal(state.bounds, group_bounds(labels[perm], 3))
    assert_array_equal(state.features, features[perm])
    for name in ("shapes", "tracks", "observed", "back_projected"):
        assert_array_equal(getattr(state, name), permute_points(before[name], perm), name)
    for name in ("sharp", "scaled"):  # (F, 3P): each coordinate block moves the same way
        moved = before[name].reshape(state.n_frames, 3, n_points)[:, :, perm]
        assert_array_equal(getattr(state, name), moved.reshape(state.n_frames, -1), name)
    for name in ("shapes", "sharp", "scaled", "work", "reprojection"):
        assert getattr(state, name).flags.c_contiguous, name
    assert state.work.shape == state.sharp.shape
    assert state.reprojection.shape == state.tracks.shape

    inverse = state.inverse_order()
    assert_array_equal(permute_points(state.shapes, inverse), before["shapes"])
    assert_array_equal(state.labels[inverse], labels)
