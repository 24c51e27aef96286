"""Result and Progress: a short repr, str-valued enums, unchanged result files."""

import json

import h5py
import numpy as np
import pytest

from moju_core import Progress, SolverParams, Stage, StopReason, reconstruct
from moju_core.datasets import make_sequence
from moju_core.io import write_result


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
