"""Projection onto orthonormal rows, and rotations fitted to given shapes."""

from __future__ import annotations

import numpy as np
import pytest
from low_rank_sequences import assert_orthonormal_rows
from numpy.testing import assert_allclose

from moju_core.cameras.refinement import fit_rotations_to_shapes, project_to_stiefel
from moju_core.metrics import rotation_error_deg


def test_project_to_stiefel_gives_orthonormal_rows_and_keeps_rotations():
    rng = np.random.default_rng(1)
    M = rng.normal(size=(50, 2, 3))
    R = project_to_stiefel(M)
    assert_orthonormal_rows(R, 50)
    # Idempotent, and a positive scale per matrix is divided out.
    assert_allclose(project_to_stiefel(R), R, atol=1e-14)
    assert_allclose(project_to_stiefel(R * rng.uniform(0.1, 10.0, size=(50, 1, 1))), R, atol=1e-13)
    # It is the nearest such matrix: no random orthonormal candidate is closer.
    candidates = project_to_stiefel(rng.normal(size=(200, 2, 3)))
    best = np.linalg.norm(M[0] - R[0])
    assert np.all(np.linalg.norm(M[0] - candidates, axis=(1, 2)) >= best - 1e-12)


def test_project_to_stiefel_works_on_any_stack_and_rejects_tall_matrices():
    rng = np.random.default_rng(2)
    R = project_to_stiefel(rng.normal(size=(4, 5, 2, 3)))
    assert R.shape == (4, 5, 2, 3)
    assert_allclose(
        np.einsum("...ia,...ja->...ij", R, R), np.broadcast_to(np.eye(2), (4, 5, 2, 2)), atol=1e-13
    )
    with pytest.raises(ValueError, match="at most as many rows as columns"):
        project_to_stiefel(rng.normal(size=(3, 2)))


def test_rotations_fitted_to_given_shapes_are_exact_from_a_nearby_start():
    rng = np.random.default_rng(11)
    truth = project_to_stiefel(rng.standard_normal((8, 2, 3)))
    shapes = rng.standard_normal((8, 3, 60))
    tracks = truth @ shapes
    start = project_to_stiefel(truth + 0.1 * rng.standard_normal(truth.shape))
    assert rotation_error_deg(start, truth) > 2.0
    fitted = fit_rotations_to_shapes(start, tracks, shapes, iterations=8)
    assert_orthonormal_rows(fitted, 8)
    assert_allclose(fitted, truth, atol=1e-10)
    # Each frame's problem is its own: the fit does not mix frames.
    fitted_one = fit_rotations_to_shapes(start[:1], tracks[:1], shapes[:1], 8)
    assert_allclose(fitted_one, fitted[:1], atol=1e-12)
