"""Tests of the geodesic bound on groups cut off from the rest of an image."""

from __future__ import annotations

import numpy as np
import pytest

from moju_core.priors.cut_off_groups import _largest_factor, hold_cut_off_groups


def _strip(n_points: int = 10, n_frames: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flat strip of points 0.1 apart at depth 2, a chain of edges, lengths in metres."""
    x = 0.1 * np.arange(n_points) - 0.45
    points = np.stack([x, np.zeros(n_points), np.full(n_points, 2.0)], axis=1)
    rays = np.broadcast_to(points[:, :2] / points[:, 2:], (n_frames, n_points, 2)).copy()
    edges = np.stack([np.arange(n_points - 1), np.arange(1, n_points)], axis=1)
    return rays, edges, np.full((n_frames, n_points), 2.0)


def _gaps(rays: np.ndarray, depths: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    q = np.concatenate([rays, np.ones(rays.shape[:1] + (1,))], axis=1)
    x = depths[:, None] * q
    return np.linalg.norm(x[a][:, None] - x[b][None], axis=2)


def test_a_group_pushed_away_is_brought_within_its_geodesic_distance():
    rays, edges, depths = _strip()
    seen = np.ones(depths.shape, bool)
    seen[1, 4:6] = False  # image 1: points 6-9 are cut off from points 0-3
    depths[1, 6:] = 8.0  # the maximum-depth push of a short group seen edge-on
    lengths = np.full(len(edges), 0.1)
    held = hold_cut_off_groups(rays, seen, edges, np.where(seen, depths, np.nan), lengths)
    # The rest is untouched; the group keeps its shape, scaled along its rays.
    assert np.array_equal(held[[0, 2]], depths[[0, 2]])
    assert np.array_equal(held[1, :4], depths[1, :4])
    ratio = held[1, 6:] / depths[1, 6:]
    assert np.allclose(ratio, ratio[0]) and ratio[0] < 0.5
    # Every point of the group within its geodesic distance of every point of the rest, and
    # one pair exactly at it (the largest such factor).
    gaps = _gaps(rays[1], held[1], np.arange(6, 10), np.arange(4))
    geodesic = 0.1 * (np.arange(6, 10)[:, None] - np.arange(4)[None])
    assert np.all(gaps <= geodesic + 1e-12)
    assert np.min(geodesic - gaps) == pytest.approx(0.0, abs=1e-12)


def test_a_group_within_reach_is_kept():
    rays, edges, depths = _strip()
    seen = np.ones(depths.shape, bool)
    seen[1, 4:6] = False
    lengths = np.full(len(edges), 0.1)
    held = hold_cut_off_groups(rays, seen, edges, np.where(seen, depths, np.nan), lengths)
    # A flat strip is exactly at its geodesic distances: kept to rounding.
    assert np.allclose(held[seen], depths[seen], rtol=1e-12, atol=0)


def test_no_factor_meets_inconsistent_bounds():
    group = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 3.0]])  # 2 apart along one ray
    rest = np.array([[0.0, 0.0, 2.0]])
    assert np.isnan(_largest_factor(group, rest, np.array([[0.5], [0.5]])))
    assert _largest_factor(group, rest, np.array([[np.inf], [np.inf]])) == 1.0
    assert _largest_factor(group, rest, np.array([[1.0], [1.0]])) == pytest.approx(1.0)


def test_a_group_beyond_reach_by_less_than_the_slack_is_kept():
    rays, edges, depths = _strip()
    seen = np.ones(depths.shape, bool)
    seen[1, 4:6] = False
    depths[1, 6:] = 2.1  # 5 % deeper: its points are a little beyond their geodesic distance
    start = np.where(seen, depths, np.nan)
    lengths = np.full(len(edges), 0.1)
    moved = hold_cut_off_groups(rays, seen, edges, start, lengths, slack=0.0)
    assert moved[1, 6] < 2.1
    kept = hold_cut_off_groups(rays, seen, edges, start, lengths, slack=0.1)
    assert np.array_equal(kept[seen], start[seen])


def test_a_group_whose_bounds_contradict_keeps_its_depths():
    rays, edges, depths = _strip()
    seen = np.ones(depths.shape, bool)
    seen[1, 4:6] = False
    lengths = np.full(len(edges), 0.1)
    lengths[3] = 0.01  # point 4 cannot be 0.01 from point 3 and on its own ray: no factor fits
    lengths[4] = 0.01
    lengths[5] = 0.01
    start = np.where(seen, depths, np.nan)
    held = hold_cut_off_groups(rays, seen, edges, start, lengths)
    assert np.array_equal(held[seen], start[seen])
