"""Starts for the consistency rounds smoothed per image (moju_core.priors.smoothed_starts)."""

from __future__ import annotations

import numpy as np

from moju_core.datasets.perspective_sheets import cylinder_sheet
from moju_core.priors.smoothed_starts import (
    bent_depths,
    local_plane_depths,
    smoothed_start_depths,
)


def _plane_and_cylinder(seed: int = 0):
    """Rays (2, P, 2) and depths (2, P) of a tilted plane (image 0) and a bent sheet (1)."""
    rays, truth = cylinder_sheet(n_points=120, n_frames=2, seed=seed)
    inverse_plane = 0.3 + 0.05 * rays[0, :, 0] - 0.08 * rays[0, :, 1]
    depths = np.stack([1.0 / inverse_plane, truth[1, :, 2]])
    return rays, depths


def test_both_starts_keep_a_plane():
    rays, depths = _plane_and_cylinder()
    np.testing.assert_allclose(bent_depths(rays, depths)[0], depths[0], rtol=1e-9)
    np.testing.assert_allclose(local_plane_depths(rays, depths)[0], depths[0], rtol=1e-6)


def test_starts_smooth_noise_away():
    rays, depths = _plane_and_cylinder(seed=1)
    rng = np.random.default_rng(0)
    noisy = depths * (1 + 0.05 * rng.standard_normal(depths.shape))
    for start in smoothed_start_depths(rays, noisy):
        assert np.abs(start - depths).mean() < 0.6 * np.abs(noisy - depths).mean()


def test_unknown_depths_stay_unknown_and_small_images_keep_theirs():
    rays, depths = _plane_and_cylinder()
    depths[1, 5:] = np.nan  # image 1: 5 depths, fewer than the bend's 6 coefficients
    depths[0, :10] = np.nan
    bent, local = smoothed_start_depths(rays, depths)
    for start in (bent, local):
        assert np.array_equal(np.isnan(start), np.isnan(depths))
    np.testing.assert_array_equal(bent[1, :5], depths[1, :5])
