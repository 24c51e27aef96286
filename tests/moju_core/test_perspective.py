"""The perspective path of reconstruct (moju_core.perspective): a camera's intrinsics given."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from moju_core import SolverParams, perspective, reconstruct
from moju_core.cameras.intrinsics import Intrinsics
from moju_core.datasets.perspective_sheets import cylinder_sheet
from moju_core.datasets.totem import out_of_plane_ratio, scaled_e3d
from moju_core.errors import MeasurementError
from moju_core.perspective import (
    _fill_hidden,
    _place_empty_frames,
    _unplaced_on_rays,
    uses_surface_prior,
)

FOCAL = 800.0
CAMERA = Intrinsics(np.array([[FOCAL, 0.0, 0.0], [0.0, FOCAL, 0.0], [0.0, 0.0, 1.0]]))


def _pixels(rays: np.ndarray) -> np.ndarray:
    """Rays (F, P, 2) as pixel tracks W (2F, P) of :data:`CAMERA`."""
    n_frames, n_points, _ = rays.shape
    return (FOCAL * rays).transpose(0, 2, 1).reshape(2 * n_frames, n_points)


@pytest.fixture(scope="module")
def sheet():
    return cylinder_sheet(n_points=120, n_frames=8, seed=1)


def _solve(W, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return reconstruct(
            W, SolverParams(seed=0, max_iter=60, **options.pop("params", {})), **options
        )


def test_a_camera_gives_depth_where_the_orthographic_solve_stays_flat(sheet):
    rays, truth = sheet
    W = _pixels(rays)
    perspective = _solve(W, intrinsics=CAMERA)
    orthographic = _solve(W)
    plan = perspective.diagnostics.plan
    assert plan.camera_model == "perspective" and plan.surface_prior == "isometric"
    assert plan.data_term == "anchored"
    assert orthographic.diagnostics.plan.camera_model == "orthographic"
    # The camera frame: points in front of the camera, mean depth 1.
    assert (perspective.shapes[..., 2] > 0).all()
    assert np.isclose(perspective.shapes[..., 2].mean(), 1.0, rtol=0.05)
    # Measured: e3D 0.091 against 0.126 orthographic (windowed cameras over 20 degrees).
    # Without the pull towards the prior (ANCHOR_WEIGHT 0) the loop flattens the sheet:
    # out-of-plane 0.56.
    error = scaled_e3d(perspective.shapes, truth)
    assert error < scaled_e3d(orthographic.shapes, truth) and error < 0.12
    assert out_of_plane_ratio(perspective.shapes, truth) > 0.6


def test_seen_points_lie_on_their_viewing_rays(sheet):
    # The tracks set where the points are seen and the solve only their depths: every seen
    # point projects back onto its track.
    rays, _ = sheet
    noisy = rays + np.random.default_rng(2).normal(scale=0.5 / FOCAL, size=rays.shape)
    W = _pixels(noisy)
    shapes = _solve(W, intrinsics=CAMERA).shapes
    projected = FOCAL * shapes[..., :2] / shapes[..., 2:3]
    np.testing.assert_allclose(projected, FOCAL * noisy, atol=1e-9)


def test_hidden_entries_are_solved_too(sheet):
    rays, truth = sheet
    visibility = np.ones(rays.shape[:2], bool)
    visibility[5:, :10] = False  # ten points lost for the last three frames
    W = np.where(np.repeat(visibility, 2, axis=0), _pixels(rays), np.nan)
    result = _solve(W, intrinsics=CAMERA, visibility=visibility)
    assert np.isfinite(result.shapes).all()
    assert scaled_e3d(result.shapes, truth) < 0.2


def test_a_hidden_point_follows_its_frame_from_the_nearest_frame_that_sees_it():
    shapes = np.zeros((3, 4, 3))
    shapes[:, :, 2] = 1.0
    shapes[1] += [0.5, 0.0, 0.0]  # frame 1 moved by 0.5 in x
    visibility = np.ones((3, 4), bool)
    visibility[1, 0] = False
    shapes[1, 0] = np.nan
    filled = _fill_hidden(shapes, visibility)
    assert np.allclose(filled[1, 0], [0.5, 0.0, 1.0])


def test_a_hidden_point_turns_with_the_object():
    # Frame 1 is frame 0 turned by 30 degrees about the vertical and moved; the point hidden
    # in frame 1 must turn with the others, not only follow their centroid.
    rng = np.random.default_rng(0)
    first = rng.normal(size=(12, 3)) + [0.0, 0.0, 4.0]
    angle = np.radians(30.0)
    cos, sin = np.cos(angle), np.sin(angle)
    turn = np.array([[cos, 0.0, sin], [0.0, 1.0, 0.0], [-sin, 0.0, cos]])
    shapes = np.stack([first, first @ turn.T + [0.2, -0.1, 0.5]])
    visibility = np.ones((2, 12), bool)
    visibility[1, 3] = False
    expected = shapes[1, 3].copy()
    shapes[1, 3] = np.nan
    filled = _fill_hidden(shapes, visibility)
    np.testing.assert_allclose(filled[1, 3], expected, atol=1e-9)


def test_a_hidden_point_whose_frames_share_no_point_with_this_one_is_still_moved():
    # Point 0 is seen in frame 0 only, with points 1-3; frame 2 sees only points 4-6, none of
    # which frame 0 sees. Frame 1 sees 1-6 and links them: point 0 reaches frame 2 through it
    # (a turning object, so the turn must be carried, not only the shift).
    rng = np.random.default_rng(2)
    first = rng.normal(size=(7, 3)) + [0.0, 0.0, 4.0]
    turns = []
    for degrees in (0.0, 20.0, 40.0):
        angle = np.radians(degrees)
        cos, sin = np.cos(angle), np.sin(angle)
        turns.append(np.array([[cos, 0.0, sin], [0.0, 1.0, 0.0], [-sin, 0.0, cos]]))
    truth = np.stack([first @ turn.T + [0.1 * f, 0.0, 0.2 * f] for f, turn in enumerate(turns)])
    visibility = np.zeros((3, 7), bool)
    visibility[0, :4] = visibility[1, 1:] = visibility[2, 4:] = True
    filled = _fill_hidden(np.where(visibility[:, :, None], truth, np.nan), visibility)
    assert np.isfinite(filled).all()
    np.testing.assert_allclose(filled, truth, atol=1e-9)


def test_one_wrong_frame_before_a_point_is_lost_is_outvoted():
    # A still object; the point is lost after frame 3 and was misplaced in frame 3, the frame
    # just before (a track is least reliable where the surface turns away).
    rng = np.random.default_rng(1)
    still = rng.normal(size=(10, 3)) + [0.0, 0.0, 4.0]
    shapes = np.repeat(still[None], 6, axis=0)
    shapes[3, 0] += [0.0, 0.0, 2.0]
    visibility = np.ones((6, 10), bool)
    visibility[4:, 0] = False
    shapes[4:, 0] = np.nan
    filled = _fill_hidden(shapes, visibility)
    np.testing.assert_allclose(filled[4:, 0], still[[0, 0]], atol=1e-9)


def test_a_point_seen_in_one_frame_is_taken_from_it():
    shapes = np.zeros((4, 5, 3))
    shapes[..., 2] = 1.0 + np.arange(5)
    visibility = np.ones((4, 5), bool)
    visibility[1:, 2] = False
    shapes[1:, 2] = np.nan
    filled = _fill_hidden(shapes, visibility)
    np.testing.assert_allclose(filled[1:, 2], [[0.0, 0.0, 3.0]] * 3)


def test_the_rule_for_the_perspective_path():
    auto = SolverParams(rotations="auto")
    assert uses_surface_prior(auto, CAMERA)
    assert not uses_surface_prior(auto, None)
    assert not uses_surface_prior(SolverParams(rotations="known"), CAMERA)
    assert not uses_surface_prior(SolverParams(surface_prior="none"), CAMERA)
    assert not uses_surface_prior(SolverParams(method="pta"), CAMERA)
    with pytest.raises(MeasurementError, match="needs the camera's intrinsics"):
        uses_surface_prior(SolverParams(surface_prior="isometric"), None)
    with pytest.raises(MeasurementError, match="method 'pta'"):
        uses_surface_prior(SolverParams(surface_prior="isometric", method="pta"), CAMERA)


def test_a_focal_length_far_too_long_is_refused_with_what_to_do():
    """Pixel tracks of an ordinary lens given a focal length of 1e12 px span 2e-8 degrees: the
    prior's cone program cannot place a point, and the error says so instead of failing later."""
    rays, _ = cylinder_sheet(n_points=80, n_frames=6, seed=0)
    pixels = rays * 500.0 + np.array([320.0, 240.0])
    W = pixels.transpose(0, 2, 1).reshape(12, -1)
    camera = Intrinsics.from_focal(1e12, (640, 480))
    with pytest.raises(MeasurementError, match="field of view .* focal length"):
        reconstruct(W, SolverParams(seed=0), intrinsics=camera)


def test_a_seen_point_without_a_depth_goes_to_its_ray_from_where_other_frames_put_it():
    # Point 0 is seen in frame 1 but the prior set no depth for it there; the fill put it
    # at (0.1, 0, 2) (from the other frames); its ray in frame 1 is the optical axis.
    homogeneous = np.zeros((2, 3, 3))
    homogeneous[..., 2] = 1.0
    depths = np.array([[2.0, 3.0, 4.0], [np.nan, 3.0, 5.0]])
    shapes = depths[..., None] * homogeneous
    shapes[1, 0] = [0.1, 0.0, 2.0]
    unplaced = np.isnan(depths)
    placed = _unplaced_on_rays(shapes, homogeneous, unplaced, depths)
    np.testing.assert_allclose(placed[1, 0], [0.0, 0.0, 2.0])
    assert np.array_equal(placed[~unplaced], shapes[~unplaced])
    # Where no frame placed it, the median depth of its image (3 and 5: 4).
    shapes[1, 0] = np.nan
    placed = _unplaced_on_rays(shapes, homogeneous, unplaced, depths)
    np.testing.assert_allclose(placed[1, 0], [0.0, 0.0, 4.0])


def test_an_image_without_a_placed_point_takes_the_nearest_image_s_depth():
    depths = np.array([[2.0, 4.0, np.nan], [np.nan] * 3, [np.nan] * 3, [5.0, np.nan, 7.0]])
    visibility = np.array([[1, 1, 0], [1, 0, 1], [0, 1, 1], [1, 0, 1]], bool)
    placed = _place_empty_frames(depths, visibility)
    np.testing.assert_allclose(placed[1], [3.0, np.nan, 3.0])  # image 0's median, not 3's
    np.testing.assert_allclose(placed[2], [np.nan, 6.0, 6.0])  # image 3's
    assert np.array_equal(placed[[0, 3]], depths[[0, 3]], equal_nan=True)
    every_image_placed = depths[[0, 3]]
    assert _place_empty_frames(every_image_placed, visibility[[0, 3]]) is every_image_placed


def test_an_image_where_the_prior_placed_nothing_still_gets_every_shape(sheet, monkeypatch):
    """The object has almost left the last image: the few points it still sees are cut off
    from one another and the cone program places none. Every entry of that image is still
    given a shape (it was NaN, and the loop then failed), the seen ones on their rays."""
    rays, _ = sheet
    visibility = np.ones(rays.shape[:2], bool)
    visibility[-1, 12:] = False
    W = np.where(np.repeat(visibility, 2, axis=0), _pixels(rays), np.nan)
    original = perspective.max_depth_shapes

    def nothing_in_the_last_image(*args, **kwargs):
        fit = original(*args, **kwargs)
        depths = fit.depths.copy()
        depths[-1] = np.nan
        return dataclasses.replace(fit, depths=depths)

    monkeypatch.setattr(perspective, "max_depth_shapes", nothing_in_the_last_image)
    shapes, _ = perspective.prior_shapes(W, visibility, CAMERA, seed=0)
    assert np.isfinite(shapes).all()
    seen = shapes[-1, :12]
    np.testing.assert_allclose(seen[:, :2] / seen[:, 2:], rays[-1, :12], atol=1e-12)
    result = _solve(W, intrinsics=CAMERA, visibility=visibility)
    assert np.isfinite(result.shapes).all()
