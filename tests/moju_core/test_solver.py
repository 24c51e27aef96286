"""End-to-end behaviour of reconstruct(): accuracy on small sequences, progress, control, errors."""

import numpy as np
import pytest
from numpy.testing import assert_array_equal
from threadpoolctl import threadpool_info, threadpool_limits

from moju_core import Cancelled, MeasurementError, SolverParams, reconstruct
from moju_core.datasets import make_sequence
from moju_core.metrics import e3d


@pytest.fixture(scope="module")
def face():
    return make_sequence("face1", n_points=600)


@pytest.mark.parametrize(
    ("method", "rotations", "limit"),
    [
        ("moju", "known", 0.05),
        ("moju", "intersection", 0.08),
        ("sdg", "known", 0.05),
        ("bmm", "known", 0.05),
    ],
)
def test_reconstructs_a_small_face_sequence(face, method, rotations, limit):
    params = SolverParams(method=method, rotations=rotations)
    result = reconstruct(face.W, params, rotations=face.rotations if rotations == "known" else None)
    assert result.shapes.shape == (10, 600, 3)
    assert result.rotations.shape == (10, 2, 3)
    assert e3d(result.shapes, face.shapes) < limit
    # Far better than the depthless initialisation S = pinv(R) W.
    depthless = np.einsum("fji,fjp->fpi", face.rotations, face.W.reshape(10, 2, -1))
    assert e3d(result.shapes, face.shapes) < 0.5 * e3d(depthless, face.shapes)
    assert result.stop_reason in ("converged", "rho_max")
    # Shapes are in the input's units: they reproject onto the tracks.
    centred = face.W - face.W.mean(axis=1, keepdims=True)
    reprojected = np.einsum("fij,fpj->fip", result.rotations, result.shapes).reshape(20, -1)
    assert np.sqrt(np.mean((reprojected - centred) ** 2)) < 1e-2 * np.sqrt(np.mean(centred**2))


def test_moju_beats_the_nuclear_norm_alone_under_noise():
    noisy = make_sequence("face1", n_points=1500, noise=0.03)
    errors = {
        method: e3d(
            reconstruct(
                noisy.W, SolverParams(method=method, rotations="known"), rotations=noisy.rotations
            ).shapes,
            noisy.shapes,
        )
        for method in ("moju", "bmm")
    }
    assert errors["moju"] < 0.9 * errors["bmm"]


def test_is_deterministic_for_a_seed(face):
    params = SolverParams(rotations="known", seed=3, max_iter=30)
    first = reconstruct(face.W, params, rotations=face.rotations)
    second = reconstruct(face.W, params, rotations=face.rotations)
    assert_array_equal(first.shapes, second.shapes)
    assert_array_equal(first.labels, second.labels)


def test_reports_progress_and_resolves_defaults(face):
    reports = []
    result = reconstruct(face.W, rotations=face.rotations, callback=reports.append)
    stages = [r.stage for r in reports]
    assert stages[:3] == ["validating", "rotations", "initialising"]
    assert stages[-1] == "finishing"
    iterations = [r.iteration for r in reports if r.stage == "iterating"]
    assert iterations == list(range(1, result.n_iter + 1))
    fractions = [r.fraction for r in reports]
    assert fractions == sorted(fractions) and 0 <= fractions[0] and fractions[-1] <= 1
    assert all(r.eta is not None and r.eta >= 0 for r in reports if r.stage == "iterating")
    assert result.params.rotations == "known"
    for name in ("n_groups", "subspace_dim", "low_dim", "n_clusters", "beta1", "beta2", "beta3"):
        assert getattr(result.params, name) is not None
    assert len(result.history["gap"]) == result.n_iter
    assert set(result.timings) >= {"rotations", "initialise", "iterate", "total"}


def test_callback_can_cancel(face):
    def stop_at_fifth(progress):
        return progress.stage == "iterating" and progress.iteration == 5

    with pytest.raises(Cancelled):
        reconstruct(face.W, rotations=face.rotations, callback=stop_at_fifth)


def test_sparse_input_falls_back_to_the_nuclear_norm():
    markers = make_sequence("face3", n_points=40)
    result = reconstruct(markers.W, rotations=markers.rotations)
    assert result.params.n_groups == 1
    assert e3d(result.shapes, markers.shapes) < 0.05


def test_output_is_independent_of_pixel_units_and_translation(face):
    # bmm: the continuous part of the loop. With local groups the discrete clustering turns
    # round-off differences into (equally good) different groupings, so moju is compared on
    # accuracy only.
    params = SolverParams(method="bmm", rotations="known", max_iter=40)
    base = reconstruct(face.W, params, rotations=face.rotations)
    scaled = reconstruct(250.0 * face.W + 17.0, params, rotations=face.rotations)
    np.testing.assert_allclose(scaled.shapes, 250.0 * base.shapes, rtol=1e-6, atol=1e-6)
    moju = SolverParams(rotations="known")
    errors = [
        e3d(reconstruct(w, moju, rotations=face.rotations).shapes, face.shapes * k)
        for w, k in ((face.W, 1.0), (250.0 * face.W + 17.0, 250.0))
    ]
    assert abs(errors[0] - errors[1]) < 0.005


def test_known_rotations_are_required_when_asked_for(face):
    with pytest.raises(MeasurementError, match="rotations of shape \\(10, 2, 3\\)"):
        reconstruct(face.W, SolverParams(rotations="known"))


def test_refuses_more_groups_than_the_points_can_fill(face):
    with pytest.raises(MeasurementError, match="n_groups=500 needs at least"):
        reconstruct(face.W, SolverParams(n_groups=500), rotations=face.rotations)


@pytest.mark.parametrize(
    ("W", "message"),
    [
        (np.zeros((7, 20)), "even number"),
        (np.zeros((2, 20)), "at least 2 frames"),
        (np.full((6, 20), np.nan), "NaN"),
    ],
)
def test_rejects_malformed_measurements(W, message):
    with pytest.raises(MeasurementError, match=message):
        reconstruct(W)


def test_unknown_parameters_are_rejected():
    with pytest.raises(ValueError, match="n_grups"):
        SolverParams(n_grups=3)


def test_windowed_rotations_are_refined_with_the_shapes():
    # The windowed estimate follows the sheet's own turning (25 degrees off here); refining it
    # with the shapes in the loop cut e3D from 0.036 to 0.012 (same prior weight).
    from moju_core.cameras import estimate_cameras
    from moju_core.preprocessing import normalise

    sheet = make_sequence("paper", n_points=1000)
    estimate = estimate_cameras(normalise(sheet.W)[0], "windowed")
    refined = reconstruct(sheet.W, SolverParams(rotations="windowed", smoothness=10.0))
    fixed = reconstruct(
        sheet.W, SolverParams(rotations="known", smoothness=10.0), rotations=estimate.rotations
    )
    assert refined.diagnostics.rotations_refined and not fixed.diagnostics.rotations_refined
    assert not np.allclose(refined.rotations, estimate.rotations)
    assert np.allclose(fixed.rotations, estimate.rotations)
    assert e3d(refined.shapes, sheet.shapes) < 0.5 * e3d(fixed.shapes, sheet.shapes)


def test_the_temporal_prior_and_the_free_mean_shape_are_resolved_per_method(face):
    moju = reconstruct(face.W, SolverParams(max_iter=5), rotations=face.rotations)
    assert moju.params.free_mean_shape is True and moju.params.smoothness is not None
    assert moju.diagnostics.smoothness_trials
    bmm = reconstruct(face.W, SolverParams(method="bmm", max_iter=5), rotations=face.rotations)
    assert bmm.params.free_mean_shape is False and bmm.params.smoothness == 0.0
    assert bmm.diagnostics.smoothness_trials == ()
    chosen = reconstruct(face.W, SolverParams(smoothness=3.0, max_iter=5), rotations=face.rotations)
    assert chosen.params.smoothness == 3.0 and chosen.diagnostics.smoothness_trials == ()


@pytest.mark.parametrize(("n_frames", "n_points"), [(60, 15), (120, 30)])
@pytest.mark.parametrize("rotations", ["known", "auto"])
def test_long_sequences_of_few_points_solve_with_the_defaults(n_frames, n_points, rotations):
    # F > 3P: every F x F or 3P x 3P choice of the solver is exercised on the tall side.
    data = make_sequence("face4", n_frames=n_frames, n_points=n_points, seed=1)
    result = reconstruct(
        data.W,
        SolverParams(rotations=rotations),
        rotations=data.rotations if rotations == "known" else None,
    )
    assert result.shapes.shape == (n_frames, n_points, 3)
    assert result.params.n_groups == 1  # too few points for local groups
    assert e3d(result.shapes, data.shapes) < 0.1


def test_a_transposed_looking_input_gives_a_result_or_a_clear_message():
    # 5000 rows of 10 columns: read as 2500 frames of 10 points.
    W = np.random.default_rng(0).standard_normal((5000, 10))
    rotations = make_sequence("face4", n_frames=2500, n_points=10).rotations
    try:
        result = reconstruct(W, SolverParams(max_iter=30), rotations=rotations)
    except MeasurementError as error:
        assert "point" in str(error) or "frame" in str(error)
    else:
        assert result.shapes.shape == (2500, 10, 3) and np.isfinite(result.shapes).all()


def _blas_threads() -> set[int]:
    return {pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}


def _blas_threads_while_iterating(face, **kwargs) -> set[int]:
    """The BLAS thread counts seen from inside the solve, at every iteration."""
    seen: set[int] = set()

    def callback(progress):
        if progress.stage == "iterating":
            seen.update(_blas_threads())

    reconstruct(
        face.W, SolverParams(max_iter=3), rotations=face.rotations, callback=callback, **kwargs
    )
    assert seen, "the callback never saw an iteration"
    return seen


def test_default_threads_keep_the_callers_limit(face):
    with threadpool_limits(limits=2):
        if _blas_threads() != {2}:
            pytest.skip("this BLAS cannot run 2 threads here")
        assert _blas_threads_while_iterating(face) == {2}


def test_threads_argument_sets_the_limit_for_the_call_only(face):
    with threadpool_limits(limits=2):
        if _blas_threads() != {2}:
            pytest.skip("this BLAS cannot run 2 threads here")
        assert _blas_threads_while_iterating(face, threads=1) == {1}
        assert _blas_threads() == {2}  # the caller's limit is back after the call
    with threadpool_limits(limits=1):
        assert _blas_threads_while_iterating(face, threads=2) == {2}


def test_unset_rotation_method_uses_given_rotations_else_estimates(face):
    assert SolverParams().rotations is None
    given = reconstruct(face.W, SolverParams(max_iter=3), rotations=face.rotations)
    assert given.params.rotations == "known"
    np.testing.assert_allclose(given.rotations, face.rotations, atol=1e-12)
    estimated = reconstruct(face.W, SolverParams(max_iter=3))
    # Result.params names the estimator "auto" chose, and running that again repeats it.
    assert estimated.params.rotations == estimated.diagnostics.rotation_source
    assert estimated.params.rotations in ("intersection", "windowed")
    again = reconstruct(face.W, SolverParams(max_iter=3, rotations=estimated.params.rotations))
    assert_array_equal(again.rotations, estimated.rotations)


@pytest.mark.parametrize("method", ["auto", "intersection", "windowed", "rigid"])
def test_an_estimating_method_with_given_rotations_is_refused(face, method):
    with pytest.raises(MeasurementError, match=f"params.rotations is '{method}', which estimates"):
        reconstruct(face.W, SolverParams(rotations=method), rotations=face.rotations)


@pytest.mark.parametrize("seed", range(4))
def test_the_test_for_shapes_off_the_object_agrees_with_the_distance_it_bounds(seed):
    from moju_core.loop.data_terms import beyond

    rng = np.random.default_rng(seed)
    shapes = rng.standard_normal((6, 3, 40)) + rng.standard_normal((6, 3, 1))  # offset frames
    shapes[rng.integers(6), :, rng.integers(40)] *= 1.0 + 10.0 * rng.random()
    distance = np.linalg.norm(shapes - shapes.mean(axis=2, keepdims=True), axis=1).max()
    for limit in (0.5 * distance, 0.999 * distance, 1.001 * distance, 2 * distance, 10 * distance):
        assert beyond(shapes, limit) == (distance > limit)
