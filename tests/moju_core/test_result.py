"""Result and Progress: a short repr, str-valued enums, typed diagnostics, result files."""

import dataclasses
import json
from importlib import resources
from pathlib import Path

import h5py
import numpy as np
import pytest

from moju_core import Progress, Result, SolverParams, Stage, StopReason, reconstruct
from moju_core.datasets import make_sequence
from moju_core.io import read_result, write_result
from moju_core.result import Diagnostics


@pytest.fixture(scope="module")
def result():
    data = make_sequence("face1", n_frames=30, n_points=400)
    return reconstruct(data.W, SolverParams(max_iter=20), rotations=data.rotations)


def test_repr_is_short_and_shows_sizes_and_scalars(result):
    text = repr(result)
    assert len(text) < 600
    assert text.startswith("Result(frames=30, points=400, method='moju', rotations='known'")
    assert "n_iter=20" in text and "stop_reason='max_iter'" in text
    assert "array" not in text and "[" not in text


def test_final_shape_gap_and_exact_fit_describe_the_end_of_the_loop(result):
    assert result.final_shape_gap == result.history["gap_shape"][-1]
    assert result.exact_fit is result.diagnostics.exact_fit
    bare = dataclasses.replace(result, history={}, diagnostics=None)
    assert bare.final_shape_gap is None and bare.exact_fit is False


def test_stop_reason_and_stage_are_str_enums(result):
    assert result.stop_reason is StopReason.MAX_ITER
    assert result.stop_reason == "max_iter" and isinstance(result.stop_reason, str)
    assert not result.converged
    assert json.dumps({"stop_reason": result.stop_reason}) == '{"stop_reason": "max_iter"}'
    progress = Progress("iterating", 1, 10, 0.1, 0.01, 0.5, 1.0, None)
    assert progress.stage is Stage.ITERATING and progress.stage == "iterating"
    assert f"{progress.stage}" == "iterating"
    with pytest.raises(ValueError):
        Progress("thinking", 1, 10, 0.1, 0.01, 0.5, 1.0, None)
    # "stopped" is the internal loop's (its hook's) stop; reconstruct raises Cancelled instead.
    with pytest.raises(ValueError, match="cannot have stop_reason 'stopped'"):
        dataclasses.replace(result, stop_reason=StopReason.STOPPED)


def test_reported_stages_are_stage_members():
    data = make_sequence("face1", n_points=200)
    stages = []
    reconstruct(data.W, SolverParams(max_iter=3), callback=lambda p: stages.append(p.stage))
    assert all(isinstance(stage, Stage) for stage in stages)
    assert list(dict.fromkeys(stages)) == [s for s in Stage if s is not Stage.TRACKING]


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_result_files_store_the_plain_string(result, tmp_path, suffix):
    path = write_result(tmp_path / f"r{suffix}", result)
    if suffix == ".npz":
        with np.load(path, allow_pickle=False) as npz:
            stored = npz["stop_reason"]
            assert stored.dtype.kind == "U" and str(stored) == "max_iter"
    else:
        with h5py.File(path, "r") as h5:
            stored = h5.attrs["stop_reason"]
            assert type(stored) is str and stored == "max_iter"


def test_diagnostics_are_typed_and_frozen(result):
    diagnostics = result.diagnostics
    assert isinstance(diagnostics, Diagnostics)
    assert diagnostics.rotation_source == "known" and diagnostics.rotation_window is None
    assert diagnostics.n_groups_used >= 1 and diagnostics.observed_fraction == 1.0
    assert isinstance(diagnostics.noise_variance, float) and diagnostics.noise_variance >= 0
    assert isinstance(diagnostics.smoothness_trials, tuple)
    with pytest.raises(dataclasses.FrozenInstanceError):
        diagnostics.n_groups_used = 3
    with pytest.raises(ValueError, match="rotation_source is 'auto'"):
        Diagnostics(n_groups_used=1, rotation_source="auto")


def test_pta_diagnostics_hold_the_trajectory_basis_fit():
    data = make_sequence("face1", n_points=200)
    fit = reconstruct(data.W, SolverParams(method="pta")).diagnostics.trajectory_basis
    assert isinstance(fit.rank, int) and fit.rank >= 1 and fit.condition >= 1.0


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_read_result_returns_the_result_that_was_written(result, tmp_path, suffix):
    path = write_result(tmp_path / f"r{suffix}", result, metadata={"job_id": "j"})
    loaded = read_result(path)
    assert type(loaded) is Result
    assert loaded.params == result.params and loaded.diagnostics == result.diagnostics
    assert loaded.stop_reason is result.stop_reason and loaded.version == result.version
    assert loaded.metadata == {"job_id": "j"} and result.metadata == {}
    assert repr(loaded) == repr(result)


def test_py_typed_ships_with_the_package():
    assert resources.files("moju_core").joinpath("py.typed").is_file()
    pyproject = Path(__file__).parents[2] / "pyproject.toml"
    assert 'moju_core = ["py.typed"]' in pyproject.read_text()  # setuptools package data
