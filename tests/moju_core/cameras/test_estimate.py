"""The camera step (estimate_cameras): every rotation method by name, and the automatic choice."""

import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose

from moju_core.cameras import estimate_cameras, windowed
from moju_core.cameras.estimate import AUTO_MARGIN
from moju_core.cameras.intersection import intersection_rotations
from moju_core.cameras.rigid import rigid_rotations
from moju_core.datasets import make_sequence
from moju_core.metrics import rotation_error_deg
from moju_core.preprocessing import normalise


def _centred(name: str, n_points: int = 1000, noise: float = 0.0) -> tuple[np.ndarray, object]:
    data = make_sequence(name, n_points=n_points, noise=noise)
    return normalise(data.W)[0], data


@pytest.mark.parametrize("name", ["face1", "face3"])
def test_auto_keeps_the_intersection_rotations_of_faces(name):
    W, data = _centred(name)
    estimate = estimate_cameras(W, "auto")
    assert estimate.source == "intersection" and not estimate.refine
    assert_allclose(estimate.rotations, intersection_rotations(W, estimate.n_bases))
    # Both candidates were measured; the windowed one was not far more rigid.
    assert estimate.rigidity["windowed"] >= AUTO_MARGIN * estimate.rigidity["intersection"]


@pytest.mark.parametrize(("name", "noise"), [("paper", 0.0), ("cloth", 0.0), ("cloth", 0.03)])
def test_auto_takes_the_windowed_rotations_of_sheets(name, noise):
    W, data = _centred(name, noise=noise)
    with warnings.catch_warnings():
        # The intersection method warns that no shape basis fits these sheets; the warning is
        # only passed on when its rotations are kept.
        warnings.simplefilter("error")
        estimate = estimate_cameras(W, "auto")
    assert estimate.source == "windowed" and estimate.refine
    rotations, window, _ = windowed.best_windowed_rotations(
        windowed.RowGram(W, max(windowed.WINDOW_LENGTHS)), rigid_rotations(W)
    )
    assert estimate.window == window
    assert_allclose(estimate.rotations, rotations)
    assert estimate.rigidity["windowed"] < AUTO_MARGIN * estimate.rigidity["intersection"]
    assert rotation_error_deg(estimate.rotations, data.rotations) < 30.0


def test_named_methods_and_the_rigid_one():
    W, _ = _centred("paper", n_points=500)
    assert estimate_cameras(W, "windowed").source == "windowed"
    rigid = estimate_cameras(W, "rigid")
    assert rigid.source == "rigid" and not rigid.refine
    assert_allclose(rigid.rotations, rigid_rotations(W))
    with pytest.warns(RuntimeWarning, match="no corrective triple fits W"):
        intersection = estimate_cameras(W, "intersection", n_bases=2)
    assert intersection.source == "intersection" and intersection.n_bases == 2
    with pytest.raises(ValueError, match="unknown rotation method 'known'"):
        estimate_cameras(W, "known")


def test_the_intersection_method_that_falls_back_to_rigid_rotations_says_so():
    """A rigid object supports one shape basis: the intersection method returns the
    Tomasi-Kanade rotations, and the estimate names them."""
    W, _ = _centred("paper", n_points=500)
    rigid = rigid_rotations(W)
    shapes = np.linalg.lstsq(rigid.reshape(-1, 3), W, rcond=None)[0]  # one 3-D shape
    W_rigid = rigid.reshape(-1, 3) @ shapes
    with pytest.warns(RuntimeWarning, match="exceeds what W supports"):
        estimate = estimate_cameras(W_rigid, "intersection", n_bases=2)
    assert estimate.source == "rigid"
    assert_allclose(estimate.rotations, rigid_rotations(W_rigid))
