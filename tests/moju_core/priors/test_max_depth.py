"""Tests of the maximum-depth surface prior on small synthetic isometric sheets."""

from __future__ import annotations

import numpy as np
import pytest

from moju_core.datasets.perspective_sheets import cylinder_sheet
from moju_core.datasets.totem import out_of_plane_ratio, scaled_e3d
from moju_core.priors.cone_program import solve_max_depth_cone
from moju_core.priors.dense_depth import interpolate_depths
from moju_core.priors.max_depth import SurfaceFit, max_depth_edges, max_depth_shapes
from moju_core.priors.neighbour_graph import neighbour_edges


@pytest.fixture(scope="module")
def sheet() -> tuple[np.ndarray, np.ndarray]:
    return cylinder_sheet()


@pytest.fixture(scope="module")
def fit(sheet) -> SurfaceFit:
    rays, _ = sheet
    return max_depth_shapes(rays)


def test_bent_sheet_recovered(sheet, fit):
    # Little rotation (20 degrees over the sequence): depth comes from the bending alone.
    # Measured: e3D 0.095, out-of-plane ratio 0.76 (a flat estimate scores about 0.25 and 0).
    rays, truth = sheet
    assert fit.status == "Solved"
    assert 2 <= fit.n_solves <= 7 and fit.shrink >= 0
    assert fit.length_scale == "edges"  # every point seen: the two scales are one program
    assert scaled_e3d(fit.shapes, truth) < 0.12
    assert out_of_plane_ratio(fit.shapes, truth) > 0.6
    flat = np.concatenate([rays, np.ones(rays.shape[:2] + (1,))], 2)
    assert scaled_e3d(flat, truth) > 2 * scaled_e3d(fit.shapes, truth)


def test_consistency_beats_plain_heuristic(sheet, fit):
    # Measured: plain maximum depth 0.179, with edge-length consistency 0.095.
    rays, truth = sheet
    plain = max_depth_shapes(rays, rigidity=0.0)
    assert scaled_e3d(fit.shapes, truth) < 0.7 * scaled_e3d(plain.shapes, truth)


def test_depths_positive_and_scale_normalised(fit, sheet):
    rays, _ = sheet
    assert np.all(fit.depths > 0)
    assert np.mean(fit.depths) == pytest.approx(1.0, rel=1e-9)
    expected = fit.depths[..., None] * np.concatenate([rays, np.ones(rays.shape[:2] + (1,))], 2)
    np.testing.assert_allclose(fit.shapes, expected)


def test_inextensibility_holds(sheet):
    rays, _ = sheet
    seen = np.ones(rays.shape[:2], bool)
    edges = neighbour_edges(rays, k=8)
    sol = solve_max_depth_cone(rays, seen, edges)
    q = np.concatenate([rays, np.ones(rays.shape[:2] + (1,))], 2)
    shapes = sol.depths[..., None] * q
    lengths = np.linalg.norm(shapes[:, edges[:, 0]] - shapes[:, edges[:, 1]], axis=2)
    assert np.all(lengths <= sol.lengths[None, :] * (1 + 1e-5) + 1e-7)
    assert np.mean(sol.lengths) == pytest.approx(1.0, rel=1e-6)
    # Every edge is tight (within 1 %) in at least one image: the depths are maximal.
    assert np.mean(lengths.max(axis=0) >= 0.99 * sol.lengths) > 0.95


def test_missing_entries(sheet):
    rays, truth = sheet
    rng = np.random.default_rng(3)
    visibility = rng.random(rays.shape[:2]) > 0.15
    masked = np.where(visibility[..., None], rays, np.nan)
    result = max_depth_shapes(masked, visibility)
    assert np.all(np.isnan(result.depths[~visibility]))
    seen_depths = result.depths[visibility]
    assert np.all(np.isfinite(seen_depths)) and np.all(seen_depths > 0)
    # Score on the points seen in every image.
    always = visibility.all(axis=0)
    assert scaled_e3d(result.shapes[:, always], truth[:, always]) < 0.15


def test_dense_stage_from_anchors():
    rays, truth = cylinder_sheet(n_points=600, n_frames=5, seed=1)
    result = max_depth_shapes(rays, n_anchor=80, seed=1)
    assert result.anchors.size == 80
    assert result.n_edges < 600  # the anchors' graph: no dense graph is built by default
    assert result.seconds["refine"] == 0.0 and result.violation == 0.0
    assert np.all(result.depths > 0)
    assert scaled_e3d(result.shapes, truth) < 0.12
    assert set(result.seconds) >= {"graph", "cone", "interpolate", "refine", "total"}


def test_dense_refinement_keeps_the_bounds():
    rays, truth = cylinder_sheet(n_points=600, n_frames=5, seed=1)
    result = max_depth_shapes(rays, n_anchor=80, seed=1, refine_iter=60)
    assert result.n_edges > 600 * 3
    assert np.all(result.depths > 0)
    assert scaled_e3d(result.shapes, truth) < 0.12
    assert result.violation < 0.01  # the dense bounds hold to 1 % on average


def test_interpolation_exact_on_a_plane():
    rng = np.random.default_rng(0)
    rays = rng.uniform(-0.3, 0.3, (2, 200, 2))
    normal = np.array([0.2, -0.1, 1.0])
    depths = 2.0 / (np.concatenate([rays, np.ones((2, 200, 1))], 2) @ normal)  # n.X = 2
    anchors = np.arange(0, 200, 5)
    out = interpolate_depths(rays, np.ones((2, 200), bool), anchors, depths[:, anchors])
    np.testing.assert_allclose(out, depths, rtol=1e-6)


def test_edges_pure_and_reproducible(sheet):
    rays, _ = sheet
    edges = max_depth_edges(rays, k=8)
    assert edges.ndim == 2 and edges.shape[1] == 2 and edges.dtype.kind == "i"
    assert np.all(edges[:, 0] < edges[:, 1])
    np.testing.assert_array_equal(edges, max_depth_edges(rays.copy(), k=8))
    a = max_depth_shapes(rays, n_anchor=40, seed=5)
    b = max_depth_shapes(rays, n_anchor=40, seed=5)
    np.testing.assert_array_equal(a.depths, b.depths)


def test_rejects_single_image():
    with pytest.raises(ValueError):
        max_depth_shapes(np.zeros((1, 10, 2)))


def test_dense_stage_with_missing_entries():
    rays, truth = cylinder_sheet(n_points=400, n_frames=5, seed=2)
    visibility = np.random.default_rng(4).random(rays.shape[:2]) > 0.2
    result = max_depth_shapes(
        np.where(visibility[..., None], rays, np.nan), visibility, n_anchor=60, seed=2
    )
    assert np.all(np.isnan(result.depths[~visibility]))
    assert np.all(result.depths[visibility] > 0)
    always = visibility.all(axis=0)
    assert scaled_e3d(result.shapes[:, always], truth[:, always]) < 0.15
