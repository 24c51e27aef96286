"""Tests of the maximum-depth program solved by key images and fixed lengths."""

from __future__ import annotations

import numpy as np
import pytest

from moju_core.datasets.perspective_sheets import cylinder_sheet
from moju_core.datasets.totem import scaled_e3d
from moju_core.priors import key_images
from moju_core.priors.cone_program import solve_max_depth_cone
from moju_core.priors.key_images import MAX_KEY_IMAGES, solve_by_key_images
from moju_core.priors.neighbour_graph import neighbour_edges


@pytest.fixture(scope="module")
def long_sheet() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rays, truth = cylinder_sheet(n_points=60, n_frames=MAX_KEY_IMAGES + 6, seed=3)
    return rays, truth, neighbour_edges(rays, k=6)


def test_an_image_alone_with_the_joint_lengths_gets_the_joint_depths(long_sheet):
    # Given the lengths the images are independent: the plain program's optimum restricted to
    # one image is that image's optimum under those lengths.
    rays, _, edges = long_sheet
    rays, seen = rays[:4], np.ones(rays[:4].shape[:2], bool)
    joint = solve_max_depth_cone(rays, seen, edges, rigidity=0.0)
    for frame in range(4):
        alone = solve_max_depth_cone(
            rays[frame : frame + 1], seen[frame : frame + 1], edges, rigidity=0.0,
            lengths=joint.lengths,
        )  # fmt: skip
        assert alone.status == "Solved"
        np.testing.assert_allclose(alone.depths[0], joint.depths[frame], rtol=1e-4)


def test_short_sequences_are_solved_jointly(long_sheet):
    rays, _, edges = long_sheet
    rays = rays[:MAX_KEY_IMAGES]
    seen = np.ones(rays.shape[:2], bool)
    by_keys = solve_by_key_images(rays, seen, edges)
    joint = solve_max_depth_cone(rays, seen, edges)
    np.testing.assert_array_equal(by_keys.depths, joint.depths)


def test_long_sequences_solve_few_images_jointly_and_stay_close(long_sheet, monkeypatch):
    rays, truth, edges = long_sheet
    seen = np.ones(rays.shape[:2], bool)
    calls: list[int] = []
    solve = key_images.solve_max_depth_cone

    def counted(rays_in, *args, **kwargs):
        calls.append(rays_in.shape[0])
        return solve(rays_in, *args, **kwargs)

    monkeypatch.setattr(key_images, "solve_max_depth_cone", counted)
    by_keys = solve_by_key_images(rays, seen, edges)
    assert max(calls) == MAX_KEY_IMAGES and calls.count(1) == rays.shape[0] - MAX_KEY_IMAGES
    assert by_keys.status == "Solved" and np.isfinite(by_keys.depths).all()
    joint = solve(rays, seen, edges)
    q = np.concatenate([rays, np.ones(rays.shape[:2] + (1,))], 2)
    e_keys = scaled_e3d(by_keys.depths[..., None] * q, truth)
    e_joint = scaled_e3d(joint.depths[..., None] * q, truth)
    assert e_keys < 1.2 * e_joint + 0.01


def test_key_images_cover_every_edge_seen_whole_somewhere():
    seen = np.ones((40, 6), bool)
    seen[:, 5] = False
    seen[33, 5] = True  # point 5 seen in one image only, not an evenly spaced one
    edges = np.array([[0, 1], [1, 2], [4, 5]])
    keys = key_images.key_images(seen, edges, n_key=4)
    assert 33 in keys and keys.size == 5
    assert list(keys[:1]) == [0] and keys[-1] == 39
