"""Perspective footage: the pinhole renderer's ground truth and the bending-sheet scenes."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from moju_core.cameras.intrinsics import Intrinsics
from moju_core.datasets.footage_scenes import FOOTAGE_KINDS, footage_scene
from moju_core.footage.perspective_render import project, render_perspective

SIZE = (160, 120)
CAMERA = Intrinsics.from_focal(1.2 * SIZE[0], SIZE)


def _sample(frame: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear grey values of an RGB frame at positions (n, 2)."""
    grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY).astype(np.float32)
    xy = xy.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(grey, xy[..., 0], xy[..., 1], cv2.INTER_LINEAR).ravel()


def _edges(faces: np.ndarray) -> np.ndarray:
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def _turning_plane(angles_deg: list[float], depth: float = 0.35) -> tuple[np.ndarray, ...]:
    """A flat 0.2 m sheet turning about the vertical axis by ``angles_deg``, (F, V, 3)."""
    scene = footage_scene("curl", n_frames=2, n_points=600, seed=0)
    flat = (scene.rest - scene.rest.mean(axis=0)) * [0.2 / scene.length, 0.2 / scene.length, 0]
    facing = np.diag([1.0, -1.0, -1.0])  # the sheet's front towards the camera
    angles = np.asarray(angles_deg)[:, None]
    turns = Rotation.from_euler("y", angles, degrees=True).as_matrix() @ facing
    shapes = np.einsum("fij,vj->fvi", turns, flat) + [0.0, 0.0, depth]
    return shapes, scene.faces, scene.uv


@pytest.fixture(scope="module")
def slanted():
    """A close sheet seen at 50-65 degrees of slant: strong perspective within the sheet."""
    shapes, faces, uv = _turning_plane([50.0, 58.0, 65.0], depth=0.3)
    return render_perspective(shapes, faces, uv, CAMERA, width=SIZE[0], height=SIZE[1])


# --- renderer ------------------------------------------------------------------------------


def test_ground_truth_is_the_projection_of_the_surface_points(slanted):
    # First frame: the surface point of each covered pixel centre projects onto it exactly
    # (the perspective-correct weights; screen-space weights on 3D vertices miss it).
    assert slanted.points_xy.shape[0] > 500
    assert np.allclose(slanted.paths_2d[0], slanted.points_xy, atol=1e-9)
    assert np.allclose(project(slanted.paths_3d, CAMERA.K), slanted.paths_2d, atol=1e-9)
    assert slanted.visible[0].all()
    assert np.array_equal(slanted.lookup(slanted.points_xy), np.arange(slanted.points_xy.shape[0]))


def test_ground_truth_points_lie_on_the_plane(slanted):
    # The sheet is planar in every frame: the points' 3D paths stay on that frame's plane.
    for f in range(slanted.n_frames):
        points = slanted.paths_3d[f]
        centred = points - points.mean(axis=0)
        assert np.linalg.svd(centred, compute_uv=False)[-1] < 1e-9


def test_ground_truth_paths_follow_the_texture(slanted):
    """Frame f at the true positions looks like frame 0 at the start positions."""
    reference = _sample(slanted.frames[0], slanted.points_xy)
    f = slanted.n_frames - 1
    seen = slanted.visible[f]
    on_path = np.abs(_sample(slanted.frames[f], slanted.paths_2d[f, seen]) - reference[seen])
    shifted = slanted.paths_2d[f, seen] + [1.5, 0.0]
    off_path = np.abs(_sample(slanted.frames[f], shifted) - reference[seen])
    assert np.median(on_path) < 3.0
    assert np.median(on_path) < 0.4 * np.median(off_path)


def test_back_facing_points_are_hidden():
    shapes, faces, uv = _turning_plane([0.0, 60.0, 120.0, 180.0])
    video = render_perspective(shapes, faces, uv, CAMERA, width=SIZE[0], height=SIZE[1])
    assert video.visible[0].all() and video.visible[1].mean() > 0.9
    # Turned by more than 90 degrees, the sheet shows its back: no point is visible.
    assert not video.visible[2:].any()
    # The back is rendered too (the second texture), not left as background.
    background = np.all(video.frames[3] == video.frames[3, 0, 0], axis=2)
    assert background.mean() < 0.95


def test_render_refuses_points_behind_the_camera():
    shapes, faces, uv = _turning_plane([0.0, 80.0], depth=0.05)
    with pytest.raises(ValueError, match="in front of the camera"):
        render_perspective(shapes, faces, uv, CAMERA, width=SIZE[0], height=SIZE[1])


# --- scenes --------------------------------------------------------------------------------


def _strain(n_points: int, kind: str, seed: int) -> float:
    """Largest relative change of a mesh edge's length over the frames."""
    scene = footage_scene(kind, n_frames=12, n_points=n_points, seed=seed)
    edges = _edges(scene.faces)
    rest = np.linalg.norm(np.diff(scene.rest[edges], axis=1)[:, 0], axis=1)
    now = np.linalg.norm(scene.shapes[:, edges[:, 0]] - scene.shapes[:, edges[:, 1]], axis=2)
    return float(np.max(np.abs(now / rest - 1.0)))


@pytest.mark.parametrize("kind", FOOTAGE_KINDS)
def test_scenes_are_isometric(kind):
    """Edges keep their length up to the chords' shortening across a bend.

    The vertices lie exactly on an isometric bend of the sheet (arc lengths are kept); a
    straight edge of length h across curvature k is shorter than its arc by (k h)^2 / 24. The
    sharpest bends (a crease of 140 degrees rounded over 6 mm) give 4 % at 1,500 vertices (h
    about 6 mm, 9 mm on the diagonals), curls and cloth folds 0.1 %; halving h divides that by
    four (measured: 4.1 %, 1.06 %, 0.28 % at 1,500, 6,000, 24,000 vertices), which a stretch
    would not.
    """
    coarse = max(_strain(1500, kind, seed) for seed in (0, 1))
    fine = max(_strain(6000, kind, seed) for seed in (0, 1))
    assert coarse < 0.05
    assert fine < 0.3 * coarse


def test_scenes_are_reproducible_by_seed():
    first = footage_scene("cloth", n_frames=5, n_points=300, seed=3)
    again = footage_scene("cloth", n_frames=5, n_points=300, seed=3)
    other = footage_scene("cloth", n_frames=5, n_points=300, seed=4)
    assert np.array_equal(first.shapes, again.shapes)
    assert not np.allclose(first.shapes, other.shapes)


@pytest.mark.parametrize("kind", FOOTAGE_KINDS)
@pytest.mark.parametrize("seed", range(4))
def test_scene_pose_ranges(kind, seed):
    scene = footage_scene(kind, n_frames=20, n_points=200, seed=seed)
    assert 0.2 <= scene.length <= 0.3
    assert 5.0 - 1e-6 <= scene.turn_deg <= 30.0 + 1e-6
    assert 0.08 - 1e-9 <= scene.depth_change <= 0.2 + 1e-9
    assert 2.0 <= scene.distance_in_lengths <= 5.0
    assert (scene.shapes[..., 2] > 0).all()
    # The centroid the pose places is the shapes' centroid.
    assert np.allclose(scene.shapes.mean(axis=1), scene.centres, atol=1e-12)


def test_scene_refuses_unknown_kind():
    with pytest.raises(ValueError, match="kind"):
        footage_scene("origami")
