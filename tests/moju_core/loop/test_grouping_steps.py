"""The local-group steps on the loop's state: subspaces, local reconstruction, regrouping."""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose, assert_array_equal

from moju_core.datasets import make_sequence
from moju_core.loop import clustering, grouping_steps
from moju_core.loop.loop_state import GroupCoefficients, initial_state, loop_settings
from moju_core.params import SolverParams

P_DIM = 3


def _grouped_state(n_groups: int = 4):
    data = make_sequence("cloth", n_frames=8, n_points=120, seed=2)
    tracks = data.W.reshape(data.n_frames, 2, data.n_points)
    tracks = tracks - tracks.mean(axis=2, keepdims=True)
    params = SolverParams(
        n_groups=n_groups,
        subspace_dim=P_DIM,
        n_clusters=2,
        low_dim=6,
        smoothness=0.0,
        free_mean_shape=True,
    )
    state = initial_state(tracks, data.rotations, 0.01, None)
    state.labels = np.arange(data.n_points) % n_groups
    state.n_groups = n_groups
    state.features = clustering.track_features(tracks.reshape(2 * data.n_frames, -1))
    state.permute(np.argsort(state.labels, kind="stable"))
    # Off the zero-depth start, so that every group spans more than p dimensions.
    state.shapes += 0.1 * np.random.default_rng(0).standard_normal(state.shapes.shape)
    settings = loop_settings(params, data.n_frames, data.n_points)
    return state, settings


def _group_ranks(state) -> list[int]:
    trajectories, bounds = state.trajectories, state.bounds
    return [
        int(np.linalg.matrix_rank(trajectories[:, bounds[i] : bounds[i + 1]], tol=1e-9))
        for i in range(state.n_groups)
    ]


def test_the_local_reconstruction_leaves_each_group_in_its_subspace() -> None:
    state, _ = _grouped_state()
    assert min(_group_ranks(state)) > P_DIM
    grouping_steps.fit_group_subspaces(state, P_DIM)
    assert state.bases.shape == (state.n_groups, 3 * state.n_frames, P_DIM)
    grouping_steps.reconstruct_groups(state, regrouped=True)
    assert max(_group_ranks(state)) == P_DIM
    for i, basis in enumerate(state.bases):  # a projection: applying it again changes nothing
        block = state.trajectories[:, state.bounds[i] : state.bounds[i + 1]]
        assert_allclose(basis @ (basis.T @ block), block, atol=1e-12)


def test_between_regroupings_the_bases_are_tracked_and_projected_on() -> None:
    state, _ = _grouped_state()
    grouping_steps.fit_group_subspaces(state, P_DIM)
    previous = state.bases
    state.shapes += 0.01 * np.random.default_rng(1).standard_normal(state.shapes.shape)
    grouping_steps.reconstruct_groups(state, regrouped=False)
    assert state.bases is not previous
    assert max(_group_ranks(state)) == P_DIM


def test_moving_trajectories_regroups_the_state_and_refits_the_bases(monkeypatch) -> None:
    state, settings = _grouped_state()
    grouping_steps.fit_group_subspaces(state, P_DIM)
    shapes_in_input_order = state.shapes[:, :, state.inverse_order()]
    moved = state.labels.copy()
    moved[:5] = 3  # five trajectories of group 0 go to group 3

    def regroup(trajectories, labels, bases, group_clusters, min_size):
        return moved

    monkeypatch.setattr(clustering, "regroup", regroup)
    group_lrr = GroupCoefficients.initial(state.n_groups, state.n_frames, 6, 0)
    relabelled = grouping_steps.move_trajectories(state, group_lrr, settings)
    assert relabelled == 5 and state.label_changes == 5
    assert state.grouping_settled == (5 <= settings.settled_moves)
    assert np.all(np.diff(state.labels) >= 0)
    assert list(np.diff(state.bounds)) == list(np.bincount(moved, minlength=4))
    assert_array_equal(state.shapes[:, :, state.inverse_order()], shapes_in_input_order)
