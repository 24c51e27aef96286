"""Grassmann points of groups, the projection metric and its kernel."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from moju_core.loop import grassmann


def _orthonormal(rng, n, p):
    q, _ = np.linalg.qr(rng.standard_normal((n, p)))
    return q


def _principal_angles_projector_distance(a, b):
    return 0.5 * np.linalg.norm(a @ a.T - b @ b.T) ** 2


def test_projection_distance_matches_embedding_definition():
    rng = np.random.default_rng(0)
    a = np.stack([_orthonormal(rng, 12, 3) for _ in range(5)])
    b = np.stack([_orthonormal(rng, 12, 3) for _ in range(5)])
    expected = [_principal_angles_projector_distance(x, y) for x, y in zip(a, b, strict=True)]
    assert_allclose(grassmann.projection_distance_sq(a, b), expected, rtol=1e-12, atol=1e-12)


def test_projection_distance_is_a_function_of_the_subspace_only():
    rng = np.random.default_rng(1)
    a = _orthonormal(rng, 10, 4)
    b = _orthonormal(rng, 10, 4)
    rotation = _orthonormal(rng, 4, 4)
    assert_allclose(
        grassmann.projection_distance_sq(a @ rotation, b),
        grassmann.projection_distance_sq(a, b),
        atol=1e-12,
    )
    assert grassmann.projection_distance_sq(a, a @ rotation) == pytest.approx(0.0, abs=1e-12)
    assert_allclose(
        grassmann.projection_distance_sq(a, b), grassmann.projection_distance_sq(b, a), atol=1e-14
    )


def test_projection_distance_of_orthogonal_subspaces_is_p():
    basis = np.eye(8)
    assert grassmann.projection_distance_sq(basis[:, :3], basis[:, 3:6]) == pytest.approx(3.0)


@pytest.mark.parametrize("n", [6, 60])  # both branches: vectorised projectors / chunked overlaps
def test_projection_kernel_matches_pairwise_overlaps_and_is_psd(n):
    rng = np.random.default_rng(2)
    bases = np.stack([_orthonormal(rng, n, 2) for _ in range(7)])
    kernel = grassmann.projection_kernel(bases)
    expected = np.array([[np.linalg.norm(x.T @ y) ** 2 for y in bases] for x in bases])
    assert_allclose(kernel, expected, atol=1e-12)
    assert np.linalg.eigvalsh(kernel).min() > -1e-10
    assert_allclose(np.diag(kernel), 2.0, atol=1e-12)


@pytest.mark.parametrize("shape", [(30, 12), (12, 30)])  # Gram route on either side
def test_top_subspace_matches_svd(shape):
    rng = np.random.default_rng(3)
    block = rng.standard_normal(shape) @ np.diag(np.linspace(3, 1, shape[1]))
    basis, values = grassmann.top_subspace(block, 3)
    u, s, _ = np.linalg.svd(block)
    assert_allclose(values, s[:3], rtol=1e-10)
    assert_allclose(basis @ basis.T, u[:, :3] @ u[:, :3].T, atol=1e-9)
    assert_allclose(basis.T @ basis, np.eye(3), atol=1e-12)


def test_refine_subspace_converges_to_the_exact_subspace():
    rng = np.random.default_rng(4)
    block = rng.standard_normal((40, 25)) * np.linspace(5, 1, 25)
    exact, values = grassmann.top_subspace(block, 3)
    basis = _orthonormal(rng, 40, 3)
    for _ in range(60):
        basis, estimates = grassmann.refine_subspace(block, basis)
    assert grassmann.projection_distance_sq(basis, exact) < 1e-10
    assert_allclose(estimates, values, rtol=1e-8)


def test_group_subspaces_and_local_reconstruction_give_rank_p_blocks():
    rng = np.random.default_rng(5)
    trajectories = rng.standard_normal((18, 50))
    bounds = np.array([0, 20, 50])
    bases, values = grassmann.group_subspaces(trajectories, bounds, 2)
    projected = grassmann.project_groups(trajectories, bounds, bases)
    for i in range(2):
        block = trajectories[:, bounds[i] : bounds[i + 1]]
        u, s, vt = np.linalg.svd(block, full_matrices=False)
        assert_allclose(
            projected[:, bounds[i] : bounds[i + 1]], (u[:, :2] * s[:2]) @ vt[:2], atol=1e-9
        )
        assert_allclose(values[i], s[:2], rtol=1e-10)


def test_track_and_project_converges_to_the_rank_p_projection():
    rng = np.random.default_rng(6)
    # Two groups, each rank 3 plus a weaker remainder (singular value gap of about 3).
    data = np.concatenate(
        [
            rng.standard_normal((24, 3)) @ rng.standard_normal((3, n)) * 3
            + rng.standard_normal((24, n))
            for n in (25, 35)
        ],
        axis=1,
    )
    bounds = np.array([0, 25, 60])
    exact, _ = grassmann.group_subspaces(data, bounds, 3)
    bases = np.stack([_orthonormal(rng, 24, 3) for _ in range(2)])
    for _ in range(80):
        work = data.copy()
        bases = grassmann.track_and_project(work, bounds, bases)
    assert_allclose(work, grassmann.project_groups(data, bounds, exact), atol=1e-8)
    assert np.all(grassmann.projection_distance_sq(bases, exact) < 1e-12)


def test_project_observed_fits_each_point_in_its_own_groups_span_on_its_weighted_frames():
    rng = np.random.default_rng(7)
    n_frames, p = 9, 3
    bounds = np.array([0, 5, 9, 14, 20])  # the second group has no hidden frame
    n_points = bounds[-1]
    bases = np.stack(
        [np.linalg.qr(rng.standard_normal((3 * n_frames, p)))[0] for _ in range(len(bounds) - 1)]
    )
    observed = rng.random((n_frames, n_points)) > 0.3
    observed[:, 5:9] = True
    observed[:3] |= True  # every point keeps 3 frames: each fit is determined
    trajectories = rng.standard_normal((3 * n_frames, n_points))
    out = grassmann.project_observed(
        trajectories.copy(), bounds, bases, observed, hidden_weight=0.2
    )
    for group in range(len(bounds) - 1):
        for j in range(bounds[group], bounds[group + 1]):
            if observed[:, j].all():
                assert_allclose(out[:, j], trajectories[:, j], atol=0)
                continue
            # Weighted least squares of the point's frames in its group's span, directly.
            sqrt_w = np.sqrt(np.where(observed[:, j], 1.0, 0.2)).repeat(3)
            c = np.linalg.lstsq(
                sqrt_w[:, None] * bases[group], sqrt_w * trajectories[:, j], rcond=None
            )[0]
            assert_allclose(out[:, j], bases[group] @ c, atol=1e-9)
