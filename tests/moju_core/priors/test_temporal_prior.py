"""The temporal smoothness prior: its operator, the filter on S# and the exact S-update."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from moju_core import SolverParams, defaults, reconstruct
from moju_core.cameras import projection
from moju_core.cameras.refinement import project_to_stiefel
from moju_core.datasets import make_sequence
from moju_core.priors import temporal_prior


def _step_inputs(n_frames: int, n_points: int, seed: int):
    """Random cameras (F, 2, 3), tracks (F, 2, P) and S-update target (F, 3, P)."""
    rng = np.random.default_rng(seed)
    rotations = project_to_stiefel(rng.standard_normal((n_frames, 2, 3)))
    tracks = rng.standard_normal((n_frames, 2, n_points))
    target = rng.standard_normal((n_frames, 3, n_points))
    return rotations, tracks, target


def test_second_differences_vanish_on_constant_velocity_only():
    difference = temporal_prior.second_differences(7)
    assert difference.shape == (5, 7)
    frames = np.arange(7.0)
    assert_allclose(difference @ (3.0 + 2.0 * frames), 0.0, atol=1e-12)
    assert np.linalg.norm(difference @ frames**2) > 1.0
    assert temporal_prior.second_differences(2).shape == (0, 2)  # nothing to penalise


@pytest.mark.parametrize(
    ("n_frames", "weight", "rho"), [(7, 2.5, 0.3), (12, 100.0, 1e-2), (4, 0.1, 50.0)]
)
def test_smooth_data_step_solves_the_coupled_system(n_frames, weight, rho):
    n_points = 9
    rotations, tracks, target = _step_inputs(n_frames, n_points, seed=n_frames)
    back_projected = projection.back_project(rotations, tracks)
    out = np.empty_like(target)
    temporal_prior.smooth_data_step(
        back_projected,
        projection.viewing_directions(rotations),
        target.copy(),
        rho,
        temporal_prior.temporal_prior(n_frames, weight),
        out,
    )
    # The 3F x 3F system written out: block-diagonal R_f^T R_f, rho I, gamma (D^T D kron I3).
    difference = temporal_prior.second_differences(n_frames)
    system = rho * np.eye(3 * n_frames) + weight * np.kron(difference.T @ difference, np.eye(3))
    for f in range(n_frames):
        system[3 * f : 3 * f + 3, 3 * f : 3 * f + 3] += rotations[f].T @ rotations[f]
    rhs = (back_projected + rho * target).reshape(3 * n_frames, n_points)
    assert_allclose(out.reshape(3 * n_frames, -1), np.linalg.solve(system, rhs), atol=1e-10)


@pytest.mark.parametrize("n_frames", [1, 2, 3, 4, 9])
def test_penalty_bands_hold_the_second_difference_penalty(n_frames):
    difference = temporal_prior.second_differences(n_frames)
    dense = difference.T @ difference
    bands = temporal_prior.penalty_bands(n_frames)
    for offset in range(3):
        assert_allclose(bands[2 - offset, offset:], np.diagonal(dense, offset), atol=0)
    assert np.all(bands[0, :2] == 0) and bands[1, 0] == 0  # unused corners of the storage


def test_smooth_data_step_solves_long_sequences_of_few_points():
    # F > 3P, the case a dense (3F x 3F) or (F x F) route handles worst.
    rng = np.random.default_rng(3)
    n_frames, n_points = 400, 5
    rotations = project_to_stiefel(rng.standard_normal((n_frames, 2, 3)))
    back_projected = projection.back_project(
        rotations, rng.standard_normal((n_frames, 2, n_points))
    )
    normals = projection.viewing_directions(rotations)
    target = rng.standard_normal((n_frames, 3, n_points))
    out = np.empty_like(target)
    prior = temporal_prior.temporal_prior(n_frames, 30.0)
    temporal_prior.smooth_data_step(back_projected, normals, target.copy(), 0.2, prior, out)
    # Residual of the normal equations, applied without forming the matrix.
    shapes = out
    in_plane = shapes - normals[:, :, None] * np.einsum("fc,fcp->fp", normals, shapes)[:, None]
    flat = shapes.reshape(n_frames, -1)
    difference = temporal_prior.second_differences(n_frames)
    smooth = (difference.T @ (difference @ flat)).reshape(shapes.shape)
    residual = in_plane + 0.2 * shapes + 30.0 * smooth - back_projected - 0.2 * target
    assert np.abs(residual).max() < 1e-9


def test_smooth_data_step_without_weight_is_the_closed_form_step():
    rng = np.random.default_rng(1)
    rotations = project_to_stiefel(rng.standard_normal((5, 2, 3)))
    back_projected = projection.back_project(rotations, rng.standard_normal((5, 2, 8)))
    normals = projection.viewing_directions(rotations)
    target = rng.standard_normal((5, 3, 8))
    out = np.empty_like(target)
    prior = temporal_prior.temporal_prior(5, 0.0)
    temporal_prior.smooth_data_step(back_projected, normals, target.copy(), 0.7, prior, out)
    assert_allclose(out, projection.data_step(back_projected, normals, target, 0.7), atol=1e-12)


def test_a_negative_or_infinite_weight_is_refused():
    for weight in (-1.0, np.inf):
        with pytest.raises(ValueError, match="finite number >= 0"):
            temporal_prior.temporal_prior(5, weight)


@pytest.mark.parametrize(("weight", "rho"), [(2.5, 0.3), (100.0, 1e-2), (0.1, 50.0)])
def test_smoothing_filter_is_the_proximal_operator_of_the_prior(weight, rho):
    n_frames = 9
    rng = np.random.default_rng(7)
    x = rng.standard_normal((n_frames, 12))
    prior = temporal_prior.temporal_prior(n_frames, weight)
    smoothing = temporal_prior.smoothing_filter(prior, rho)
    y = smoothing(x)
    smoother = smoothing.matrix()
    assert_allclose(smoother @ x, y, atol=1e-12)
    difference = temporal_prior.second_differences(n_frames)
    # Optimality of gamma/2 ||D Y||^2 + rho/2 ||Y - X||^2: gamma D^T D Y + rho (Y - X) = 0.
    assert_allclose(weight * difference.T @ difference @ y + rho * (y - x), 0.0, atol=1e-10)
    gains = np.linalg.eigvalsh(smoother)
    assert gains.min() > 0 and gains.max() <= 1 + 1e-12
    frames = np.arange(n_frames, dtype=float)
    linear = np.stack([np.ones(n_frames), frames, 2.0 - 0.5 * frames], axis=1)
    assert_allclose(smoother @ linear, linear, atol=1e-10)  # constant velocity passes


@pytest.mark.parametrize(("rotations", "exact"), [("known", False), ("windowed", True)])
def test_the_loop_solves_the_prior_exactly_only_when_it_refits_the_cameras(
    monkeypatch, rotations, exact
):
    calls = {"exact": 0, "filter": 0}
    real_step, real_filter = temporal_prior.smooth_data_step, temporal_prior.smoothing_filter

    def counted_step(*args, **kwargs):
        calls["exact"] += 1
        return real_step(*args, **kwargs)

    def counted_filter(*args, **kwargs):
        calls["filter"] += 1
        return real_filter(*args, **kwargs)

    monkeypatch.setattr(temporal_prior, "smooth_data_step", counted_step)
    monkeypatch.setattr(temporal_prior, "smoothing_filter", counted_filter)
    data = make_sequence("paper", n_points=300, noise=0.01)  # noisy: the data term stays soft
    result = reconstruct(
        data.W,
        SolverParams(rotations=rotations, smoothness=10.0, max_iter=5),
        rotations=data.rotations if rotations == "known" else None,
    )
    assert result.diagnostics.rotations_refined is exact
    assert (calls["exact"] > 0) is exact
    assert (calls["filter"] > 0) is not exact


@pytest.mark.parametrize(("n_frames", "weight", "rho"), [(7, 2.5, 0.3), (12, 100.0, 1e-2)])
def test_depth_step_fits_the_tracks_and_is_optimal_over_the_depths(n_frames, weight, rho):
    rotations, tracks, target = _step_inputs(n_frames, 6, seed=n_frames)
    normals = projection.viewing_directions(rotations)
    prior = temporal_prior.temporal_prior(n_frames, weight)
    out = np.empty_like(target)
    temporal_prior.depth_step(
        projection.back_project(rotations, tracks), normals, target, rho, prior, out
    )
    assert_allclose(projection.project(rotations, out), tracks, atol=1e-10)
    # Optimality over the depths: N^T (gamma (D^T D kron I3) S + rho (S - T)) = 0.
    difference = temporal_prior.second_differences(n_frames)
    flat = out.reshape(n_frames, -1)
    gradient = (weight * (difference.T @ (difference @ flat))).reshape(out.shape)
    gradient += rho * (out - target)
    assert_allclose(np.einsum("fc,fcp->fp", normals, gradient), 0.0, atol=1e-9)


@pytest.mark.parametrize(
    ("noise", "masked", "known", "steps"),
    [
        (0.0, False, True, {"depth"}),
        (0.01, False, True, set()),
        (0.0, True, True, {"masked"}),
        (0.01, True, True, set()),
        (0.0, True, False, set()),  # estimated cameras: untrusted entries keep it soft
    ],
)
def test_the_loop_fits_exactly_only_tracks_without_noise(monkeypatch, noise, masked, known, steps):
    steps_by_name = {"depth": "depth_step", "masked": "masked_depth_step"}
    calls = dict.fromkeys(steps_by_name, 0)

    def counted(name, real):
        def wrapper(*args, **kwargs):
            calls[name] += 1
            return real(*args, **kwargs)

        return wrapper

    for name, attribute in steps_by_name.items():
        monkeypatch.setattr(
            temporal_prior, attribute, counted(name, getattr(temporal_prior, attribute))
        )
    data = make_sequence("paper", n_points=300, noise=noise)
    W = data.W.copy()
    if masked:
        W[4:, :5] = np.nan  # five points seen in 2 frames: their completions are not trusted
    reconstruct(
        W, SolverParams(smoothness=10.0, max_iter=5), rotations=data.rotations if known else None
    )
    assert {name for name, count in calls.items() if count} == steps


@pytest.mark.parametrize(("n_frames", "weight", "rho"), [(12, 7.0, 0.5), (9, 100.0, 1e-2)])
@pytest.mark.parametrize("every_point_hidden", [True, False])
def test_masked_depth_step_fits_the_measured_entries_and_places_the_hidden_ones(
    n_frames, weight, rho, every_point_hidden
):
    rotations, tracks, target = _step_inputs(n_frames, 6, seed=n_frames)
    rng = np.random.default_rng(n_frames)
    hidden = rng.random((n_frames, 6)) < 0.35
    # Every point with a hidden frame (whole arrays), or two seen in every frame (gathered).
    hidden[0] = every_point_hidden
    hidden[:, :2] &= every_point_hidden
    anchored = hidden & (rng.random((n_frames, 6)) < 0.5)
    normals = projection.viewing_directions(rotations)
    prior = temporal_prior.temporal_prior(n_frames, weight)
    back_projected = projection.back_project(rotations, tracks)
    shapes = np.empty_like(target)
    given = target.copy()
    temporal_prior.masked_depth_step(
        back_projected, ~hidden, anchored, normals, target, rho, prior, shapes
    )
    assert_allclose(target, given, rtol=0, atol=0)  # the filter works on a copy
    image = projection.project(rotations, shapes)
    seen = np.broadcast_to(~hidden[:, None, :], tracks.shape)
    assert_allclose(image[seen], tracks[seen], atol=1e-12)
    # Hidden entries: the filtered target's image position, pulled to the track if anchored.
    difference = temporal_prior.second_differences(n_frames)
    smoothing = np.linalg.inv(np.eye(n_frames) + (weight / rho) * difference.T @ difference)
    filtered = projection.project(rotations, np.einsum("fg,gcp->fcp", smoothing, target))
    pull = anchored[:, None, :].astype(float)
    expected = (rho * filtered + pull * tracks) / (rho + pull)
    unseen = np.broadcast_to(hidden[:, None, :], tracks.shape)
    assert_allclose(image[unseen], expected[unseen], atol=1e-10)
    # The depths are optimal for those image positions (the depth step's condition).
    flat = shapes.reshape(n_frames, -1)
    gradient = (weight * (difference.T @ (difference @ flat))).reshape(shapes.shape)
    gradient += rho * (shapes - target)
    assert_allclose(np.einsum("fc,fcp->fp", normals, gradient), 0.0, atol=1e-9)


@pytest.mark.parametrize("every_point_hidden", [True, False])
def test_masked_depth_step_leaves_its_target_alone_at_the_row_sweeps_size(every_point_hidden):
    # 3 x 130 columns: the filter runs as the in-place row sweep.
    n_points = 130
    rotations, tracks, target = _step_inputs(8, n_points, seed=4)
    hidden = np.zeros((8, n_points), dtype=bool)
    hidden[3, : n_points if every_point_hidden else n_points - 1] = True
    normals = projection.viewing_directions(rotations)
    back_projected = projection.back_project(rotations, tracks)
    given, shapes = target.copy(), np.empty_like(target)
    temporal_prior.masked_depth_step(
        back_projected, ~hidden, hidden, normals, target, 0.3,
        temporal_prior.temporal_prior(8, 20.0), shapes,
    )  # fmt: skip
    assert 3 * (hidden.any(axis=0).sum()) >= temporal_prior.ROW_SWEEP_MIN_COLUMNS
    assert_allclose(target, given, rtol=0, atol=0)
    image = projection.project(rotations, shapes)
    seen = np.broadcast_to(~hidden[:, None, :], tracks.shape)
    assert_allclose(image[seen], tracks[seen], atol=1e-12)


def test_masked_depth_step_without_hidden_entries_is_the_depth_step():
    rotations, tracks, target = _step_inputs(11, 5, seed=3)
    normals = projection.viewing_directions(rotations)
    prior = temporal_prior.temporal_prior(11, 30.0)
    back_projected = projection.back_project(rotations, tracks)
    expected, shapes = np.empty_like(target), np.empty_like(target)
    temporal_prior.depth_step(back_projected, normals, target, 0.4, prior, expected)
    every = np.ones((11, 5), dtype=bool)
    temporal_prior.masked_depth_step(
        back_projected, every, ~every, normals, target, 0.4, prior, shapes
    )
    assert_allclose(shapes, expected, rtol=0, atol=0)


def test_the_depth_step_with_its_kept_pull_is_the_same_step():
    rotations, tracks, target = _step_inputs(9, 7, seed=5)
    back_projected = projection.back_project(rotations, tracks)
    normals = projection.viewing_directions(rotations)
    prior = temporal_prior.temporal_prior(9, 30.0)
    computed, kept = np.empty_like(target), np.empty_like(target)
    temporal_prior.depth_step(back_projected, normals, target, 0.5, prior, computed)
    pull = temporal_prior.depth_pull(back_projected, normals, prior)
    temporal_prior.depth_step(back_projected, normals, target, 0.5, prior, kept, pull=pull)
    assert_allclose(kept, computed, rtol=1e-12, atol=1e-12)


def test_an_exact_fit_stops_at_the_gap_it_can_resolve():
    data = make_sequence("paper", n_points=300)
    result = reconstruct(data.W, SolverParams(smoothness=100.0), rotations=data.rotations)
    assert result.stop_reason == "converged"
    assert result.diagnostics.exact_fit
    assert result.history["gap_shape"][-1] < defaults.EXACT_GAP_PRECISION
    assert result.n_iter < defaults.expected_iterations(result.params)  # before rho_max
    noisy = make_sequence("paper", n_points=300, noise=0.03)
    soft = reconstruct(
        noisy.W, SolverParams(smoothness=100.0, max_iter=5), rotations=noisy.rotations
    )
    assert not soft.diagnostics.exact_fit


@pytest.mark.parametrize("n_rows", [1, 2, 3, 17])
@pytest.mark.parametrize("n_columns", [3, 400])  # LAPACK's route and the row sweep
def test_the_factored_band_solve_matches_lapack(n_rows, n_columns):
    from scipy.linalg import cho_solve_banded, cholesky_banded

    assert 3 < temporal_prior.ROW_SWEEP_MIN_COLUMNS <= 400
    rng = np.random.default_rng(n_columns)
    normals = projection.viewing_directions(project_to_stiefel(rng.standard_normal((n_rows, 2, 3))))
    bands = temporal_prior.depth_bands(normals, 0.7, temporal_prior.temporal_prior(n_rows, 40.0))
    factor = cholesky_banded(bands)
    rhs = rng.standard_normal((n_rows, n_columns))
    expected = cho_solve_banded((factor, False), rhs)
    assert_allclose(temporal_prior.solve_factored_bands(factor, rhs.copy()), expected, atol=1e-12)
