"""moju_viewer.data: the subset of shown points, depth, frames, summary, lazy result files."""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest
from numpy.testing import assert_allclose

from moju_core import reconstruct
from moju_core.datasets import make_sequence
from moju_core.io import write_result
from moju_core.params import SolverParams
from moju_viewer.data import (
    ResultView,
    camera_depth,
    frame_data,
    open_result,
    shown_points,
    summary,
    viewer_document,
)


@pytest.fixture(scope="module")
def sequence():
    return make_sequence("face1", n_points=300)


@pytest.fixture(scope="module")
def result(sequence):
    return reconstruct(sequence.W, SolverParams(max_iter=30))


def test_shown_points_are_all_or_a_fixed_sorted_subset() -> None:
    assert_allclose(shown_points(300, 300), np.arange(300))
    assert_allclose(shown_points(300, 20_000), np.arange(300))
    subset = shown_points(50_000, 20_000)
    assert subset.shape == (20_000,)
    assert np.all(np.diff(subset) > 0) and subset[0] >= 0 and subset[-1] < 50_000
    np.testing.assert_array_equal(subset, shown_points(50_000, 20_000))
    # Spread over the whole range, not the first points.
    assert subset[-1] > 49_000 and subset[0] < 1_000
    with pytest.raises(ValueError, match="max_points must be at least 1, got 0"):
        shown_points(10, 0)


def test_depth_is_the_coordinate_along_the_optical_axis() -> None:
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    points = np.array([[1.0, 2.0, 3.0], [-1.0, 0.5, -2.0]])
    assert_allclose(camera_depth(points, rotation), [3.0, -2.0])
    # A camera turned 90 degrees about y: image x is the old -z, depth the old x.
    turned = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    assert_allclose(camera_depth(points, turned), [1.0, -1.0])
    # Always orthogonal to the image axes: projecting and adding depth is a rotation.
    rng = np.random.default_rng(1)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    cloud = rng.normal(size=(20, 3))
    camera = np.column_stack([cloud @ q[0], cloud @ q[1], camera_depth(cloud, q[:2])])
    assert_allclose(np.linalg.norm(camera, axis=1), np.linalg.norm(cloud, axis=1))


def test_frame_data_rounds_to_a_fraction_of_the_extent(result) -> None:
    view = ResultView.of(result)
    indices = shown_points(view.n_points, 100)
    frame = frame_data(view, 2, indices)
    expected = result.shapes[2][indices]
    # Rounded to a power of ten no larger than 1e-4 of the largest coordinate.
    tolerance = 0.5e-4 * np.abs(expected).max() * (1 + 1e-9)
    assert_allclose(np.column_stack([frame["x"], frame["y"], frame["z"]]), expected, atol=tolerance)
    assert max(len(repr(value)) for value in frame["x"]) <= 9  # e.g. -0.12345
    with pytest.raises(IndexError, match="frame 10 is outside 0..9"):
        frame_data(view, 10, indices)


def test_summary_keeps_triangles_only_with_every_point(result, sequence) -> None:
    view = ResultView.of(result)
    full = summary(view, shown_points(300, 300), faces=sequence.faces, colors=sequence.colors)
    assert full["faces"] == sequence.faces.tolist()
    assert full["point_indices"] is None and not full["decimated"]
    part = summary(view, shown_points(300, 120), faces=sequence.faces, colors=sequence.colors)
    assert part["faces"] is None and part["decimated"]
    assert part["shown_points"] == len(part["labels"]) == len(part["colors"]) == 120
    # NaN in the history is null in JSON.
    with_nan = dataclasses.replace(view, history={"gap": np.array([np.nan, 0.5])})
    assert summary(with_nan, shown_points(300, 300))["history"] == {"gap": [None, 0.5]}


def test_open_result_reads_hdf5_lazily_and_npz_alike(result, tmp_path) -> None:
    h5_path = write_result(tmp_path / "result.h5", result)
    npz_path = write_result(tmp_path / "result.npz", result)
    with open_result(h5_path) as lazy:
        assert isinstance(lazy.shapes, h5py.Dataset)
        from_h5 = viewer_document(lazy, max_points=80)
    with open_result(npz_path) as loaded:
        from_npz = viewer_document(loaded, max_points=80)
    assert from_h5 == from_npz
    assert from_h5["summary"]["n_iter"] == result.n_iter
    assert [frame["frame"] for frame in from_h5["frames"]] == list(range(10))

    not_a_result = tmp_path / "tracks.h5"
    with h5py.File(not_a_result, "w") as h5:
        h5["W"] = np.zeros((4, 3))
    with pytest.raises(ValueError, match="tracks.h5 is not a readable MoJu result file"):
        with open_result(not_a_result):
            pass


def test_frames_list_the_points_the_solver_filled_in(result, tmp_path) -> None:
    visibility = np.ones((10, 300), dtype=bool)
    visibility[4, [3, 50, 299]] = False
    visibility[7, 10:20] = False
    occluded = dataclasses.replace(result, visibility=visibility)
    view = ResultView.of(occluded)
    everything = shown_points(300, 300)
    assert frame_data(view, 4, everything)["unobserved"] == [3, 50, 299]
    assert frame_data(view, 7, everything)["unobserved"] == list(range(10, 20))
    assert frame_data(view, 0, everything)["unobserved"] == []
    # Positions in the shown subset, not point numbers.
    subset = np.array([0, 3, 9, 299])
    assert frame_data(view, 4, subset)["unobserved"] == [1, 3]
    assert summary(view, everything)["observed_fraction"] == pytest.approx(1 - 13 / 3000)
    # The same through a stored file, read lazily from HDF5.
    with open_result(write_result(tmp_path / "occluded.h5", occluded)) as lazy:
        assert isinstance(lazy.visibility, h5py.Dataset)
        document = viewer_document(lazy)
    assert document["frames"][7]["unobserved"] == list(range(10, 20))
    assert document["summary"]["observed_fraction"] == pytest.approx(1 - 13 / 3000)


def test_complete_results_have_nothing_filled_in(result) -> None:
    document = viewer_document(ResultView.of(result), max_points=50)
    assert document["summary"]["observed_fraction"] == 1.0
    assert all(frame["unobserved"] == [] for frame in document["frames"])
