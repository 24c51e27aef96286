"""Method ``pta``: the DCT trajectory basis, its linear system, exact recovery and its limits."""

import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from moju_core import MeasurementError, SolverParams, defaults, pta, reconstruct
from moju_core.datasets import make_sequence
from moju_core.metrics import e3d, rigid_approximation


def trajectory_sequence(n_frames=30, n_points=200, n_bases=4, seed=0):
    """Shapes whose trajectories lie exactly in the first ``n_bases`` DCT vectors, seen by a
    camera with random orientations."""
    rng = np.random.default_rng(seed)
    basis = pta.dct_basis(n_frames, n_bases)
    coefficients = rng.standard_normal((n_bases, 3, n_points))
    coefficients[0] *= 3.0  # a dominant mean shape, as in real sequences
    shapes = np.einsum("fk,kcp->fpc", basis, coefficients)
    shapes -= shapes.mean(axis=1, keepdims=True)
    rotations = Rotation.random(n_frames, random_state=seed).as_matrix()[:, :2, :]
    W = np.einsum("fij,fpj->fip", rotations, shapes).reshape(2 * n_frames, n_points)
    return W + 5.0, rotations, shapes  # an image offset, removed by the solver


def test_dct_basis_is_orthonormal_with_a_constant_first_vector():
    basis = pta.dct_basis(17, 9)
    assert basis.shape == (17, 9)
    assert_allclose(basis.T @ basis, np.eye(9), atol=1e-12)
    assert_allclose(basis[:, 0], np.full(17, 1 / np.sqrt(17)))
    # Vector k has k sign changes (k / 2 cycles).
    assert [int(np.sum(np.diff(np.sign(basis[:, k])) != 0)) for k in range(9)] == list(range(9))


def test_dct_basis_matches_scipy_dct():
    from scipy.fft import dct

    n_frames = 12
    full = dct(np.eye(n_frames), type=2, norm="ortho", axis=0).T  # columns: basis vectors
    assert_allclose(pta.dct_basis(n_frames, 5), full[:, :5], atol=1e-12)


def test_dct_basis_rejects_sizes_outside_the_frames():
    with pytest.raises(ValueError, match="between 1 and the number of frames 5"):
        pta.dct_basis(5, 6)


def test_system_equals_the_explicit_kronecker_product():
    _, rotations, _ = trajectory_sequence(n_frames=6, n_points=10, n_bases=3)
    basis = pta.dct_basis(6, 3)
    block_r = np.zeros((12, 18))
    for f in range(6):
        block_r[2 * f : 2 * f + 2, 3 * f : 3 * f + 3] = rotations[f]
    # Trajectory form: row 3f + c of S, column 3k + c of A.
    expected = block_r @ np.kron(basis, np.eye(3))
    assert_allclose(pta.trajectory_system(rotations, basis), expected, atol=1e-14)


@pytest.mark.parametrize(("n_frames", "n_bases"), [(30, 4), (12, 8), (9, 6)])
def test_recovers_trajectories_in_the_basis_exactly(n_frames, n_bases):
    W, rotations, shapes = trajectory_sequence(n_frames=n_frames, n_bases=n_bases)
    result = reconstruct(
        W, SolverParams(method="pta", trajectory_bases=n_bases), rotations=rotations
    )
    # Known rotations fix the world frame: no rotation alignment is needed.
    assert e3d(result.shapes, shapes, "sign") < 1e-8
    assert result.params.trajectory_bases == n_bases


def test_solve_matches_a_dense_least_squares_solve():
    rng = np.random.default_rng(1)
    _, rotations, _ = trajectory_sequence(n_frames=10, n_points=5)
    tracks = rng.standard_normal((10, 2, 40))  # not in the model: a true least-squares fit
    shapes, diagnostics = pta.solve(tracks, rotations, 3)
    system = pta.trajectory_system(rotations, pta.dct_basis(10, 3))
    coefficients = np.linalg.lstsq(system, tracks.reshape(20, 40), rcond=None)[0]
    expected = np.einsum("fk,kcp->fcp", pta.dct_basis(10, 3), coefficients.reshape(3, 3, 40))
    assert_allclose(shapes, expected, atol=1e-12)
    assert diagnostics["rank"] == 9
    assert 1 <= diagnostics["condition"] < 1e4


def test_reasonable_on_a_smooth_face_sequence():
    face = make_sequence("face3", n_points=600)
    result = reconstruct(face.W, SolverParams(method="pta"), rotations=face.rotations)
    error = e3d(result.shapes, face.shapes)
    assert error < 0.03
    # Far better than the best rigid shape (what k = 1 would give at most).
    assert error < 0.5 * e3d(rigid_approximation(face.shapes), face.shapes)
    assert result.params.trajectory_bases > 1


def test_default_basis_is_the_largest_well_conditioned_one():
    face = make_sequence("face3", n_points=50)
    size = defaults.trajectory_basis_size(face.rotations)
    assert 3 * size <= 2 * face.n_frames

    def condition(k):
        singular = np.linalg.svd(
            pta.trajectory_system(face.rotations, pta.dct_basis(face.n_frames, k)),
            compute_uv=False,
        )
        return singular[0] / singular[-1]

    assert condition(size) <= defaults.PTA_MAX_CONDITION < condition(size + 1)


def test_a_camera_that_does_not_move_is_reported():
    W, rotations, _ = trajectory_sequence(n_frames=10, n_points=50, n_bases=2)
    still = np.repeat(rotations[:1], 10, axis=0)
    with pytest.warns(RuntimeWarning, match="PTA system has rank"):
        result = reconstruct(W, SolverParams(method="pta", trajectory_bases=2), rotations=still)
    assert np.all(np.isfinite(result.shapes))
    # The default basis of a still camera is the rigid one (k = 1), which is still solvable
    # only up to depth: the warning says so too.
    assert defaults.trajectory_basis_size(still) == 1


def test_default_basis_solves_without_warning_on_a_moving_camera():
    W, rotations, _ = trajectory_sequence(n_frames=20, n_points=50, n_bases=3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        reconstruct(W, SolverParams(method="pta"), rotations=rotations)


def test_refuses_a_basis_larger_than_the_frames_support():
    W, rotations, _ = trajectory_sequence(n_frames=10, n_points=50, n_bases=2)
    with pytest.raises(MeasurementError, match="trajectory_bases=7 needs 3k <= 2F"):
        reconstruct(W, SolverParams(method="pta", trajectory_bases=7), rotations=rotations)
