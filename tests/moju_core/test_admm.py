"""The ADMM loop's stopping rule: shape gap below tol and the grouping settled."""

from __future__ import annotations

import numpy as np
import pytest

from moju_core import SolverParams, clustering, reconstruct
from moju_core.datasets import make_sequence
from moju_core.defaults import SETTLED_MOVE_FRACTION


def _regroup_moving(count: int):
    """A regrouping that keeps the labels but for ``count`` trajectories that always move
    (as boundary trajectories between two nearly equal subspaces do)."""
    calls = {"n": 0}

    def regroup(trajectories, labels, bases, group_clusters, min_size):
        calls["n"] += 1
        moved = labels.copy()
        first = np.flatnonzero(labels == labels[0])[:count]
        moved[first] = labels[-1]  # from the first group to the last: both stay large
        return moved

    return regroup


@pytest.mark.parametrize(("moving", "expected"), [(2, "converged"), (3, "rho_max")])
def test_a_few_endlessly_moving_trajectories_do_not_block_convergence(
    monkeypatch, moving: int, expected: str
) -> None:
    n_points = 2000
    assert int(SETTLED_MOVE_FRACTION * n_points) == 2  # the threshold this test straddles
    data = make_sequence("face1", n_points=n_points, seed=3)
    monkeypatch.setattr(clustering, "regroup", _regroup_moving(moving))
    params = SolverParams(method="moju", rotations="known")
    result = reconstruct(data.W, params, rotations=data.rotations)
    assert result.stop_reason == expected
    relabelled = result.history["relabelled"]
    assert np.all(relabelled[relabelled > 0] == moving)
