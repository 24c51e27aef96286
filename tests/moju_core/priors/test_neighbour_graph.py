"""Tests of the neighbour graph and the anchor sampling of the surface prior."""

from __future__ import annotations

import numpy as np

from moju_core.priors.neighbour_graph import largest_groups, neighbour_edges, spread_anchors


def _grid(n_frames: int = 3) -> np.ndarray:
    gx, gy = np.meshgrid(np.arange(10.0), np.arange(6.0))
    base = np.stack([gx.ravel(), gy.ravel()], 1) / 10
    return np.stack([base * (1 + 0.05 * f) for f in range(n_frames)])


def test_grid_neighbours():
    edges = neighbour_edges(_grid(), k=4)
    lengths = np.linalg.norm(_grid()[0][edges[:, 0]] - _grid()[0][edges[:, 1]], axis=1)
    assert np.all(edges[:, 0] < edges[:, 1])
    assert len(np.unique(edges, axis=0)) == len(edges)
    # 4 nearest on a 0.1 grid: steps, diagonals, and double steps at a border.
    assert np.all(lengths <= 0.2 + 1e-9)
    assert len(edges) >= 9 * 6 + 10 * 5


def test_edges_only_where_seen():
    rays = _grid()
    visibility = np.ones(rays.shape[:2], bool)
    visibility[:, 0] = False  # point 0 never seen
    edges = neighbour_edges(np.where(visibility[..., None], rays, np.nan), visibility, k=4)
    assert 0 not in edges


def test_unstable_neighbours_dropped():
    rays = _grid(4)
    # Point 0 jumps far away in 3 of 4 frames: its first-frame neighbours are not stable.
    rays[1:, 0] = [5.0, 5.0]
    edges = neighbour_edges(rays, k=4)
    assert not np.any(np.all(edges == [0, 1], axis=1))


def test_anchors_spread_and_seeded():
    rays = _grid()
    anchors = spread_anchors(rays, n_anchor=4, seed=0)
    assert anchors.size == 4 and len(set(anchors)) == 4
    pts = rays[0, anchors]
    gaps = np.linalg.norm(pts[:, None] - pts[None], axis=2)[np.triu_indices(4, 1)]
    assert gaps.min() > 0.3  # spread over the 0.9 x 0.5 image, not clustered
    np.testing.assert_array_equal(anchors, spread_anchors(rays, n_anchor=4, seed=0))
    assert spread_anchors(rays, n_anchor=1000).size == 60


def test_largest_groups_keep_the_largest_group_of_each_image():
    chain = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5]])
    seen = np.ones((4, 6), bool)
    seen[1, 2] = False  # image 1: {0, 1} and {3, 4, 5}
    seen[2, 3] = False  # image 2: {0, 1, 2} and {4, 5}
    seen[3] = False  # image 3 sees nothing
    placed = largest_groups(seen, chain)
    assert placed[0].all()
    assert placed[1].tolist() == [False, False, False, True, True, True]
    assert placed[2].tolist() == [True, True, True, False, False, False]
    assert not placed[3].any()


def test_largest_groups_tie_goes_to_the_earliest_group():
    chain = np.array([[0, 1], [1, 2], [2, 3]])
    seen = np.array([[True, True, False, True], [True, False, True, True]])
    placed = largest_groups(seen, chain)
    assert placed[0].tolist() == [True, True, False, False]
    assert placed[1].tolist() == [False, False, True, True]
