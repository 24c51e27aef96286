"""How reconstruct() takes its parameters and what it says about a W that looks transposed."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from moju_core import reconstruct
from moju_core.datasets import make_sequence
from moju_core.errors import MeasurementError


def test_parameters_as_a_mapping() -> None:
    W = make_sequence("face1", n_points=60).W
    result = reconstruct(W, {"max_iter": 5, "seed": 1})
    assert result.params.max_iter == 5 and result.n_iter <= 5


def test_parameters_of_another_type_are_a_type_error() -> None:
    with pytest.raises(TypeError, match="SolverParams or a mapping"):
        reconstruct(np.zeros((4, 10)), [("max_iter", 5)])  # type: ignore[arg-type]


def test_a_transposed_w_is_named() -> None:
    W = make_sequence("face1", n_points=500).W  # 2F x P = 20 x 500
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # Read as 250 frames x 20 points; "known" rotations that are not given stop the call
        # right after the checks, so the test does not wait for a solve.
        with pytest.raises(MeasurementError, match="rotations"):
            reconstruct(W.T, {"rotations": "known"})
    assert any("pass W.T" in str(w.message) for w in caught), [str(w.message) for w in caught]


def test_dense_tracks_get_no_transposition_warning() -> None:
    W = make_sequence("face1", n_points=60).W
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reconstruct(W, {"max_iter": 3})
    assert not any("pass W.T" in str(w.message) for w in caught)
