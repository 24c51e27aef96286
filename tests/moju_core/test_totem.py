"""Tests of the ToTem loader and scorer (skipped where the data are absent, e.g. on CI)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from moju_core.datasets.totem import (
    TOTEM_NAMES,
    load_totem,
    out_of_plane_ratio,
    pixels_to_rays,
    scaled_e3d,
)

DATA = Path(os.environ.get("MOJU_TOTEM_DIR", "/work/shared/data/totem"))
# Published scores of the reference depths (data README): MDH, MaxRig.
PUBLISHED = {
    "kinectPaper": (0.058, 0.059),
    "whiteCartoonTshirt": (0.064, 0.064),
    "hulk": (0.075, 0.074),
    "cushion": (0.120, 0.113),
}


@pytest.fixture(scope="module", params=TOTEM_NAMES)
def sequence(request):
    if not (DATA / f"data_{request.param}.mat").exists():
        pytest.skip(f"ToTem data not found in {DATA}")
    return load_totem(DATA, request.param)


def test_shapes_consistent(sequence):
    n_frames, n_points, _ = sequence.pixels.shape
    assert sequence.truth.shape == (n_frames, n_points, 3)
    assert sequence.rays.shape == (n_frames, n_points, 2)
    assert sequence.visibility.shape == (n_frames, n_points)
    assert sequence.K.shape == (3, 3) and sequence.K[2, 2] == 1
    for depths in sequence.reference_depths.values():
        assert depths.shape == (n_frames, n_points) and np.all(depths > 0)
    # The truth lies in front of the camera and (roughly) on the tracked rays.
    assert np.all(sequence.truth[..., 2] > 0)
    projected = sequence.truth[..., :2] / sequence.truth[..., 2:3]
    assert np.median(np.abs(projected - sequence.rays)) * sequence.K[0, 0] < 3.0


def test_references_reproduced(sequence):
    mdh, maxrig = PUBLISHED[sequence.name]
    assert scaled_e3d(sequence.reference_shapes("MDH"), sequence.truth) == pytest.approx(
        mdh, abs=6e-4
    )
    assert scaled_e3d(sequence.reference_shapes("MaxRig"), sequence.truth) == pytest.approx(
        maxrig, abs=6e-4
    )


def test_scorer_invariances():
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(3, 30, 3)) + [0, 0, 5]
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    moved = (truth * [[[2.0]], [[0.5]], [[3.0]]]) @ q + 1.0  # per-image scale, rotation, shift
    assert scaled_e3d(moved, truth) < 1e-12
    assert out_of_plane_ratio(moved, truth) == pytest.approx(1.0)
    flat = truth.copy()
    flat[..., 2] = 5.0
    assert out_of_plane_ratio(flat, truth) < 1.0


def test_pixels_to_rays():
    K = np.array([[800.0, 0, 320], [0, 810, 240], [0, 0, 1]])
    rays = pixels_to_rays(np.array([[320.0, 240.0], [1120.0, 1050.0], [np.nan, 1.0]]), K)
    np.testing.assert_allclose(rays[:2], [[0, 0], [1, 1]])
    assert np.isnan(rays[2, 0])
