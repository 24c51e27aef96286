"""The scikit-learn estimator moju_core.MoJu."""

import inspect

import numpy as np
import pytest
from numpy.testing import assert_array_equal
from pydantic import ValidationError
from sklearn.base import clone
from sklearn.exceptions import NotFittedError
from sklearn.utils.validation import check_is_fitted

from moju_core import MoJu, SolverParams, reconstruct
from moju_core.datasets import make_sequence


@pytest.fixture(scope="module")
def face():
    return make_sequence("face1", n_points=300)


def test_hyper_parameters_are_the_schema_fields_with_the_schema_defaults():
    signature = inspect.signature(MoJu)
    assert all(p.kind is p.KEYWORD_ONLY for p in signature.parameters.values())
    fields = SolverParams.model_fields
    solver = {k: p.default for k, p in signature.parameters.items() if k in fields}
    assert list(solver) == list(SolverParams.model_fields)
    assert solver == SolverParams().model_dump()
    assert set(signature.parameters) - set(solver) == {"threads", "callback"}


def test_get_set_params_and_clone():
    model = MoJu(max_iter=30, rotations="auto", n_groups=4)
    params = model.get_params()
    assert params["max_iter"] == 30 and params["rotations"] == "auto" and params["seed"] == 0
    assert model.set_params(seed=5, tol=0.0) is model
    assert (model.seed, model.tol) == (5, 0.0)
    copy = clone(model)
    assert copy is not model and copy.get_params() == model.get_params()
    with pytest.raises(ValueError, match="Invalid parameter"):
        model.set_params(max_itr=3)


def test_constructor_stores_values_unchanged_and_fit_validates(face):
    model = MoJu(max_iter=-1, method="nonsense")  # no error yet: scikit-learn's convention
    assert model.max_iter == -1 and model.method == "nonsense"
    with pytest.raises(ValidationError, match="max_iter"):
        model.fit(face.W)
    with pytest.raises(NotFittedError):
        check_is_fitted(model)


@pytest.mark.parametrize("known", [True, False])
def test_fit_equals_reconstruct(face, known):
    rotations = face.rotations if known else None
    model = MoJu(max_iter=20, seed=1)
    assert model.fit(face.W, rotations=rotations) is model
    expected = reconstruct(face.W, SolverParams(max_iter=20, seed=1), rotations=rotations)
    check_is_fitted(model)
    assert model.shapes_.shape == (10, 300, 3)
    assert_array_equal(model.shapes_, expected.shapes)
    assert_array_equal(model.rotations_, expected.rotations)
    assert_array_equal(model.labels_, expected.labels)
    assert model.n_iter_ == expected.n_iter == 20
    assert model.stop_reason_ is expected.stop_reason
    assert model.diagnostics_ == expected.diagnostics
    assert model.result_.params == expected.params
    # A clone is unfitted and fits to the same answer.
    fresh = clone(model)
    with pytest.raises(NotFittedError):
        check_is_fitted(fresh)
    assert_array_equal(fresh.fit(face.W, rotations=rotations).shapes_, model.shapes_)


def test_fit_passes_callback_and_visibility(face):
    stages = []
    visibility = np.ones((10, 300), dtype=bool)
    visibility[2, :20] = False
    W = face.W.copy()
    W[4:6, :20] = np.nan
    model = MoJu(max_iter=3, callback=lambda p: stages.append(p.stage)).fit(
        W, rotations=face.rotations, visibility=visibility
    )
    assert stages[0] == "validating" and "iterating" in stages
    assert_array_equal(model.result_.visibility, visibility)
