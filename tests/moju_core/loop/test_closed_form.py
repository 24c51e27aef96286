"""Method ``pta`` in the loop's output form."""

import numpy as np

from moju_core.cameras import projection
from moju_core.datasets import make_sequence
from moju_core.loop.closed_form import solve_pta
from moju_core.result import StopReason


def test_one_converged_iteration_with_the_fit_of_the_solve():
    data = make_sequence("face1", n_points=150, noise=0.01, seed=3)
    n_frames = data.rotations.shape[0]
    tracks = data.W.reshape(n_frames, 2, -1)
    calls = []
    out = solve_pta(tracks, data.rotations, 3, lambda *args: calls.append(args) or False)
    assert calls == [(1, 0.0, 0.0)]
    assert out.n_iter == 1 and out.stop_reason is StopReason.CONVERGED and out.n_groups == 1
    assert not out.labels.any() and out.labels.shape == (tracks.shape[2],)
    residual = projection.project(data.rotations, out.shapes) - tracks
    assert out.history["reprojection"] == [np.sqrt(np.mean(residual**2))]
    assert 0 < out.history["reprojection"][0] < 0.1 * np.sqrt(np.mean(tracks**2))
    assert out.trajectory_basis.rank >= 1


def test_hidden_entries_leave_the_reprojection_error():
    data = make_sequence("face1", n_points=150, noise=0.01, seed=3)
    n_frames = data.rotations.shape[0]
    tracks = data.W.reshape(n_frames, 2, -1).copy()
    observed = np.random.default_rng(0).random((n_frames, tracks.shape[2])) > 0.2
    tracks[np.broadcast_to(~observed[:, None, :], tracks.shape)] = 1e6  # never read
    out = solve_pta(tracks, data.rotations, 3, lambda *args: False, observed)
    assert np.all(np.isfinite(out.shapes))
    assert out.history["reprojection"][0] < 0.1 * np.sqrt(np.mean(data.W**2))
