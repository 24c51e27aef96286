"""``moju reconstruct``, ``moju evaluate`` and ``moju demo``.

Most tests call the click commands in-process through :class:`click.testing.CliRunner` on a
300-point face sequence (half a second per solve); two run the installed ``moju`` console
script as a real process, one of them interrupted with SIGINT as Ctrl-C would.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner, Result
from numpy.testing import assert_allclose
from threadpoolctl import threadpool_info, threadpool_limits

import moju_cli.solver_commands as solver_commands
import moju_core.solver
from moju_cli.main import cli
from moju_core.datasets import make_sequence
from moju_core.io import (
    Measurements,
    read_measurements,
    read_result,
    write_measurements,
    write_result,
)
from moju_core.metrics import evaluate
from moju_core.params import SolverParams
from moju_core.ply import read_ply_points
from moju_core.result import Diagnostics
from moju_core.result import Result as SolverResult
from moju_core.validation import with_missing

N_FRAMES, N_POINTS = 10, 300
REPO = Path(__file__).resolve().parents[2]
# Parameters that keep the solver iterating for minutes on the long input (below), so that it
# is surely interrupted: 10,000 iterations of 99 frames x 4,000 points, about 17 ms each on a
# 2-core machine, 3 minutes (the 10 x 300 input runs them in 5 s, and such a run can end before
# the interrupt lands).
LONG_RUN = ["--max-iter", "10000", "--tol", "0", "--rho-growth", "1.0005", "--rho-max", "1e12"]
LONG_RUN += ["--rotations", "known"]


@pytest.fixture(scope="module")
def sequence():
    return make_sequence("face1", n_points=N_POINTS)


@pytest.fixture(scope="module")
def inputs(sequence, tmp_path_factory) -> dict[str, Path]:
    """The sequence as a full input (W, R, gt, faces, colors) and as bare tracks (W only)."""
    directory = tmp_path_factory.mktemp("inputs")
    full = Measurements(
        W=sequence.W,
        rotations=sequence.rotations,
        ground_truth=sequence.shapes,
        faces=sequence.faces,
        colors=sequence.colors,
    )
    paths = {"full": directory / "full.npz", "tracks": directory / "tracks.npz"}
    write_measurements(paths["full"], full)
    write_measurements(paths["tracks"], Measurements(W=sequence.W))
    return paths


@pytest.fixture(scope="module")
def long_input(tmp_path_factory) -> Path:
    """A sequence large enough that ``LONG_RUN`` takes minutes: face3, 4,000 points."""
    data = make_sequence("face3", n_points=4_000)
    path = tmp_path_factory.mktemp("long") / "long.npz"
    write_measurements(path, Measurements(W=data.W, rotations=data.rotations))
    return path


@pytest.fixture(scope="module")
def reconstructed(inputs, tmp_path_factory) -> tuple[Path, Result]:
    """One ``moju reconstruct`` of the full input with estimated rotations (the file's R is
    then only scored against), shared by the read-only tests."""
    output = tmp_path_factory.mktemp("reconstructed") / "result.npz"
    outcome = run(
        ["reconstruct", str(inputs["full"]), "-o", str(output), "-q", "--rotations", "auto"]
    )
    assert outcome.exit_code == 0, outcome.output
    return output, outcome


def run(args: list[str]) -> Result:
    return CliRunner().invoke(cli, args)


def assert_clean_failure(outcome: Result, exit_code: int, *fragments: str) -> None:
    """Failed with ``exit_code``, a message holding every fragment, and no traceback."""
    assert outcome.exit_code == exit_code, outcome.output
    # CliRunner catches what escapes the command; a clean failure is click's own SystemExit.
    assert isinstance(outcome.exception, SystemExit), repr(outcome.exception)
    assert "Traceback" not in outcome.output
    for fragment in fragments:
        assert fragment in outcome.output


def printed_scores(text: str) -> dict[str, float]:
    """The scores of ``_format_scores`` read back from command output."""
    scores = {}
    for key, label in solver_commands.SCORE_LABELS.items():
        match = re.search(rf"^{re.escape(label)}:\s+([0-9.eE+-]+)$", text, re.MULTILINE)
        if match:
            scores[key] = float(match.group(1))
    return scores


@pytest.fixture
def solver_must_not_run(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("the solver ran although the command line was invalid")

    monkeypatch.setattr(moju_core.solver, "reconstruct", refuse)


def moju_command() -> list[str]:
    """The installed ``moju`` console script (the entry point through Python as a fallback)."""
    script = shutil.which("moju")
    if script is not None:
        return [script]
    return [sys.executable, "-c", "import sys; from moju_cli.main import cli; sys.exit(cli())"]


def subprocess_environment() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    return env


# --------------------------------------------------------------------------------------------
# reconstruct


def test_every_schema_field_is_an_option():
    options = {
        option
        for parameter in solver_commands.reconstruct.params
        for option in parameter.opts
        if isinstance(parameter, click.Option)
    }
    for name in SolverParams.model_fields:
        assert "--" + name.replace("_", "-") in options


def test_reconstruct_round_trip(reconstructed, sequence):
    output, outcome = reconstructed
    stored = read_result(output)
    assert stored.shapes.shape == (N_FRAMES, N_POINTS, 3)
    assert stored.rotations.shape == (N_FRAMES, 2, 3)
    assert np.isfinite(stored.shapes).all()
    assert stored.params.rotations in ("intersection", "windowed")  # what "auto" chose
    assert stored.metadata["input"] == "full.npz"
    assert f"{N_FRAMES} frames x {N_POINTS} points: {stored.n_iter} iterations" in outcome.output
    assert str(output) in outcome.output
    # The printed e3D is the one of the written shapes, and the reconstruction is good.
    expected = evaluate(stored.shapes, sequence.shapes, stored.rotations, sequence.rotations)
    shown = printed_scores(outcome.stdout)
    assert set(shown) == set(expected)
    for key, value in expected.items():
        assert shown[key] == pytest.approx(value, abs=0.006)
    assert expected["e3d_procrustes"] < 0.1


def test_solver_options_reach_the_solver(inputs, tmp_path):
    output = tmp_path / "result.npz"
    args = ["--max-iter", "7", "--regroup-every", "2", "--seed", "3", "--method", "bmm"]
    outcome = run(["reconstruct", str(inputs["tracks"]), "-o", str(output), "-q", *args])
    assert outcome.exit_code == 0, outcome.output
    stored = read_result(output)
    assert stored.n_iter == 7
    assert stored.stop_reason == "max_iter"
    assert (stored.params.max_iter, stored.params.regroup_every) == (7, 2)
    assert (stored.params.seed, stored.params.method) == (3, "bmm")
    assert "e3D" not in outcome.output  # no ground truth in this input


@pytest.mark.parametrize(("args", "expected"), [([], 1), (["--threads", "2"], 2)])
def test_threads_option_limits_blas_threads(inputs, tmp_path, monkeypatch, args, expected):
    """The count is read from inside the solve (the progress callback), not around it."""
    solve, seen = moju_core.solver.reconstruct, set()

    def recording(*args, callback, **kwargs):
        def inside(progress):
            if progress.stage == "iterating":
                seen.update(p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas")
            return callback(progress)

        return solve(*args, callback=inside, **kwargs)

    monkeypatch.setattr(moju_core.solver, "reconstruct", recording)
    output = tmp_path / "r.npz"
    # Whatever the process's limit was: the option decides.
    with threadpool_limits(limits=3 - expected):
        outcome = run(["reconstruct", str(inputs["tracks"]), "-o", str(output), "-q", *args])
    assert outcome.exit_code == 0, outcome.output
    assert seen == {expected}
    assert output.exists()


def test_solver_warnings_are_one_line_messages(inputs, tmp_path, monkeypatch):
    solve = moju_core.solver.reconstruct

    def warning(*args, **kwargs):
        warnings.warn("rotations look degenerate", RuntimeWarning, stacklevel=1)
        return solve(*args, **kwargs)

    monkeypatch.setattr(moju_core.solver, "reconstruct", warning)
    outcome = run(["reconstruct", str(inputs["tracks"]), "-o", str(tmp_path / "r.npz"), "-q"])
    assert outcome.exit_code == 0, outcome.output
    assert "warning: rotations look degenerate" in outcome.stderr
    assert "RuntimeWarning" not in outcome.stderr  # no source path and category of Python's


def test_reconstruct_h5_output_and_ply_frames(inputs, sequence, tmp_path):
    output, ply_dir = tmp_path / "result.h5", tmp_path / "frames" / "ply"
    outcome = run(
        ["reconstruct", str(inputs["full"]), "-o", str(output), "--ply-dir", str(ply_dir), "-q"]
    )
    assert outcome.exit_code == 0, outcome.output
    assert output.read_bytes()[:4] == b"\x89HDF"
    stored = read_result(output)
    assert stored.shapes.shape == (N_FRAMES, N_POINTS, 3)
    frames = sorted(ply_dir.glob("*.ply"))
    assert len(frames) == N_FRAMES
    assert f"{N_FRAMES} files" in outcome.output
    assert_allclose(read_ply_points(frames[3]), stored.shapes[3], rtol=1e-6, atol=1e-6)
    # Faces and colours of the input are in the PLY header.
    header = frames[0].read_bytes()[:400]
    assert f"element face {len(sequence.faces)}".encode() in header
    assert b"property uchar red" in header


def test_reconstruct_reads_csv(sequence, tmp_path):
    source, output = tmp_path / "tracks.csv", tmp_path / "result.npz"
    write_measurements(source, Measurements(W=sequence.W))
    outcome = run(["reconstruct", str(source), "-o", str(output), "-q"])
    assert outcome.exit_code == 0, outcome.output
    assert read_result(output).shapes.shape == (N_FRAMES, N_POINTS, 3)


def test_reconstruct_with_known_rotations(inputs, sequence, tmp_path):
    output = tmp_path / "result.npz"
    outcome = run(
        ["reconstruct", str(inputs["full"]), "-o", str(output), "--rotations", "known", "-q"]
    )
    assert outcome.exit_code == 0, outcome.output
    stored = read_result(output)
    assert stored.params.rotations == "known"
    assert_allclose(stored.rotations, sequence.rotations, atol=1e-12)
    shown = printed_scores(outcome.stdout)
    assert "rotation_error_deg" not in shown  # zero by construction, so not printed
    assert shown["e3d_procrustes"] < 0.1


def test_default_rotations_are_the_files_R_when_it_has_one(inputs, sequence, tmp_path):
    output = tmp_path / "result.npz"
    outcome = run(["reconstruct", str(inputs["full"]), "-o", str(output), "-q", "--max-iter", "5"])
    assert outcome.exit_code == 0, outcome.output
    stored = read_result(output)
    assert stored.params.rotations == "known"
    assert_allclose(stored.rotations, sequence.rotations, atol=1e-12)
    assert "rotation_error_deg" not in printed_scores(outcome.stdout)


def test_known_rotations_without_R_is_a_clean_error(inputs, tmp_path, solver_must_not_run):
    output = tmp_path / "result.npz"
    outcome = run(["reconstruct", str(inputs["tracks"]), "-o", str(output), "--rotations", "known"])
    assert_clean_failure(outcome, 1, "no dataset R", "--rotations auto")
    assert not output.exists()


@pytest.mark.parametrize("name", ["result.ply", "result", "result.csv"])
def test_unknown_output_extension_is_refused_before_solving(
    inputs, tmp_path, name, solver_must_not_run
):
    outcome = run(["reconstruct", str(inputs["tracks"]), "-o", str(tmp_path / name)])
    assert_clean_failure(outcome, 2, ".npz", ".h5", ".hdf5")
    assert list(tmp_path.iterdir()) == []


def test_missing_output_directory_is_refused_before_solving(inputs, tmp_path, solver_must_not_run):
    outcome = run(["reconstruct", str(inputs["tracks"]), "-o", str(tmp_path / "no" / "r.npz")])
    assert_clean_failure(outcome, 2, "does not exist")


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        (b"hello world\n1,2\n", "frame,point,x,y"),  # text without the CSV header
        (b"PK\x03\x04truncated zip", "npz"),
        (b"\x89HDF\r\n\x1a\nnot really hdf5", "HDF5"),
    ],
)
def test_bad_input_file_is_a_clean_error(tmp_path, content, fragment, solver_must_not_run):
    source = tmp_path / "input.dat"
    source.write_bytes(content)
    outcome = run(["reconstruct", str(source), "-o", str(tmp_path / "out.npz")])
    assert_clean_failure(outcome, 1, fragment)
    assert not (tmp_path / "out.npz").exists()


def test_unusable_tracks_are_a_clean_error(tmp_path):
    source = tmp_path / "nan.npz"
    W = make_sequence("face1", n_points=50).W
    W[3, 7] = np.nan
    np.savez(source, W=W)
    outcome = run(["reconstruct", str(source), "-o", str(tmp_path / "out.npz")])
    assert_clean_failure(outcome, 1, "NaN")


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--max-iter", "0"], "--max-iter"),
        (["--tol", "-1"], "--tol"),
        (["--rho-growth", "0.5"], "--rho-growth"),
        (["--method", "lsq"], "--method"),
        (["--rotations", "guess"], "--rotations"),
        (["--n-groups", "many"], "--n-groups"),
        (["--bogus", "1"], "--bogus"),
    ],
)
def test_invalid_solver_parameters_are_usage_errors(
    inputs, tmp_path, args, fragment, solver_must_not_run
):
    outcome = run(["reconstruct", str(inputs["tracks"]), "-o", str(tmp_path / "r.npz"), *args])
    assert_clean_failure(outcome, 2, fragment, "Usage:")


def test_solver_input_error_is_a_clean_error(inputs, tmp_path):
    # Valid for the schema, impossible for 300 points: the solver's MeasurementError.
    output = tmp_path / "r.npz"
    outcome = run(["reconstruct", str(inputs["tracks"]), "-o", str(output), "--n-groups", "500"])
    assert_clean_failure(outcome, 1, "n_groups=500")
    assert not output.exists()


def test_ctrl_c_while_solving_exits_130_without_output(inputs, tmp_path, monkeypatch):
    def interrupted(W, params, *, rotations=None, callback=None, threads=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(moju_core.solver, "reconstruct", interrupted)
    output = tmp_path / "r.npz"
    outcome = run(["reconstruct", str(inputs["full"]), "-o", str(output), "-q"])
    assert outcome.exit_code == 130
    assert "interrupted" in outcome.stderr
    assert "Traceback" not in outcome.output
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_while_writing_frames_removes_this_runs_files(inputs, tmp_path, monkeypatch):
    (tmp_path / "keep.txt").write_text("not ours")
    write_frames = solver_commands.write_ply_frames

    def interrupted_after_two_frames(directory, shapes, *, faces=None, colors=None):
        write_frames(directory, shapes[:2], faces=faces, colors=colors)
        raise KeyboardInterrupt

    monkeypatch.setattr(solver_commands, "write_ply_frames", interrupted_after_two_frames)
    output, ply_dir = tmp_path / "r.npz", tmp_path / "new" / "ply"
    outcome = run(
        ["reconstruct", str(inputs["full"]), "-o", str(output), "--ply-dir", str(ply_dir), "-q"]
    )
    assert outcome.exit_code == 130
    # The result, the frames and the directories this run made are gone; the rest stays.
    assert sorted(path.name for path in tmp_path.iterdir()) == ["keep.txt"]


# --------------------------------------------------------------------------------------------
# evaluate


def test_evaluate_text_and_json_agree_with_metrics(reconstructed, inputs, sequence):
    output, _ = reconstructed
    stored = read_result(output)
    expected = evaluate(stored.shapes, sequence.shapes, stored.rotations, sequence.rotations)

    as_json = run(["evaluate", str(output), "--gt", str(inputs["full"]), "--json"])
    assert as_json.exit_code == 0, as_json.output
    scores = json.loads(as_json.stdout)
    assert set(scores) == {"e3d_procrustes", "e3d_global", "e3d_sign", "rotation_error_deg"}
    for key, value in expected.items():
        assert scores[key] == pytest.approx(value, rel=1e-12)

    as_text = run(["evaluate", str(output), "--gt", str(inputs["full"])])
    assert as_text.exit_code == 0, as_text.output
    shown = printed_scores(as_text.stdout)
    assert set(shown) == set(expected)
    for key, value in expected.items():
        assert shown[key] == pytest.approx(value, abs=0.006)
    assert "only meaningful for known rotations" in as_text.stdout


def test_evaluate_without_R_leaves_out_the_rotation_error(reconstructed, sequence, tmp_path):
    output, _ = reconstructed
    truth = tmp_path / "truth.h5"
    write_measurements(truth, Measurements(W=sequence.W, ground_truth=sequence.shapes))
    outcome = run(["evaluate", str(output), "--gt", str(truth), "--json"])
    assert outcome.exit_code == 0, outcome.output
    assert set(json.loads(outcome.stdout)) == {"e3d_procrustes", "e3d_global", "e3d_sign"}


def test_evaluate_needs_ground_truth(reconstructed, inputs):
    output, _ = reconstructed
    outcome = run(["evaluate", str(output), "--gt", str(inputs["tracks"])])
    assert_clean_failure(outcome, 1, "no ground truth", "gt")


def test_evaluate_refuses_mismatched_files(reconstructed, tmp_path):
    output, _ = reconstructed
    other = make_sequence("face1", n_points=N_POINTS + 10)
    truth = tmp_path / "other.npz"
    write_measurements(truth, Measurements(W=other.W, ground_truth=other.shapes))
    outcome = run(["evaluate", str(output), "--gt", str(truth)])
    assert_clean_failure(outcome, 1, "does not match")


def test_evaluate_refuses_a_non_result(inputs):
    outcome = run(["evaluate", str(inputs["full"]), "--gt", str(inputs["full"])])
    assert_clean_failure(outcome, 1, "not a readable MoJu result")


# --------------------------------------------------------------------------------------------
# missing data


#: True once the solver takes a visibility mask; the end-to-end tests below need it.
SOLVER_TAKES_VISIBILITY = "visibility" in inspect.signature(moju_core.solver.reconstruct).parameters


def occlusion(n_frames: int = N_FRAMES, n_points: int = N_POINTS) -> np.ndarray:
    """A band of points 40..99 hidden in frames 3..6, plus point 7 lost from frame 8 on."""
    visibility = np.ones((n_frames, n_points), dtype=bool)
    visibility[3:7, 40:100] = False
    visibility[8:, 7] = False
    return visibility


@pytest.fixture(scope="module")
def occluded_input(sequence, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("occluded") / "occluded.npz"
    measurements = Measurements(
        W=with_missing(sequence.W, occlusion()),
        rotations=sequence.rotations,
        ground_truth=sequence.shapes,
    )
    return write_measurements(path, measurements)


def fake_solution(sequence, visibility: np.ndarray | None) -> SolverResult:
    """A result as the solver would return it: the truth, off by 0.1 at the occluded entries."""
    shapes = sequence.shapes.copy()
    if visibility is not None:
        shapes[~visibility] += 0.1
    return SolverResult(
        shapes=shapes,
        rotations=sequence.rotations,
        labels=np.zeros(N_POINTS, dtype=np.int64),
        history={},
        timings={"total": 0.0},
        params=SolverParams(),
        n_iter=0,
        stop_reason="converged",
        scale=1.0,
        visibility=visibility,
    )


def test_reconstruct_hands_the_visibility_to_the_solver(occluded_input, sequence, tmp_path,
                                                         monkeypatch):  # fmt: skip
    calls = []

    def solver(W, params, *, rotations=None, callback=None, visibility=None, threads=None):
        calls.append((W, visibility))
        return fake_solution(sequence, visibility)

    monkeypatch.setattr(moju_core.solver, "reconstruct", solver)
    output = tmp_path / "result.h5"
    outcome = run(["reconstruct", str(occluded_input), "-o", str(output), "-q"])
    assert outcome.exit_code == 0, outcome.output
    ((W, visibility),) = calls
    assert visibility.dtype == bool
    np.testing.assert_array_equal(visibility, occlusion())
    assert np.isnan(W[np.repeat(~occlusion(), 2, axis=0)]).all()
    observed = occlusion().mean()
    assert f"({100 * observed:.1f} % observed)" in outcome.stdout
    np.testing.assert_array_equal(read_result(output).visibility, occlusion())
    # gt in the input: the occluded entries are scored too.
    assert "e3D of the occluded entries, Procrustes:" in outcome.stdout


@pytest.mark.parametrize(
    ("completion", "expected"),
    [
        ({}, None),
        (
            {"completion_rank": 13, "exact_completion": True},
            "hidden entries: completed by an exact rank-13 model of the tracks",
        ),
        (
            {"completion_rank": 3, "completion_unexplained": 0.004},
            "a rank-3 model, whose error on held-out observed entries beyond the noise is "
            "0.4 % of a rank-1 model's",
        ),
        ({"completion_rank": 5, "completion_unexplained": 0.12}, "12.0 % of a rank-1 model's"),
    ],
)  # fmt: skip
def test_the_summary_says_how_the_hidden_entries_were_completed(completion, expected):
    diagnostics = Diagnostics(n_groups_used=1, rotation_source="known", **completion)
    line = solver_commands._completion_line(diagnostics)
    assert line == expected if expected is None else expected in line


def test_complete_input_reaches_the_solver_without_a_mask(inputs, sequence, tmp_path,
                                                          monkeypatch):  # fmt: skip
    calls = []

    def solver(W, params, *, rotations=None, callback=None, threads=None, **masked):
        calls.append(masked)
        return fake_solution(sequence, None)

    monkeypatch.setattr(moju_core.solver, "reconstruct", solver)
    outcome = run(["reconstruct", str(inputs["full"]), "-o", str(tmp_path / "r.npz"), "-q"])
    assert outcome.exit_code == 0, outcome.output
    assert calls == [{}]
    assert "observed" not in outcome.stdout and "occluded" not in outcome.stdout


def test_evaluate_reports_the_occluded_entries(occluded_input, sequence, tmp_path):
    result_path = write_result(tmp_path / "r.npz", fake_solution(sequence, occlusion()))
    expected = evaluate(sequence.shapes + 0.1 * ~occlusion()[..., None], sequence.shapes,
                        sequence.rotations, sequence.rotations, visibility=occlusion())  # fmt: skip
    as_json = run(["evaluate", str(result_path), "--gt", str(occluded_input), "--json"])
    assert as_json.exit_code == 0, as_json.output
    scores = json.loads(as_json.stdout)
    assert set(scores) == set(expected) and "e3d_occluded_procrustes" in scores
    for key, value in expected.items():
        assert scores[key] == pytest.approx(value, rel=1e-12)
    # The shift of 0.1 is all at the occluded entries: they score far worse than the whole.
    assert scores["e3d_occluded_sign"] > 2 * scores["e3d_sign"] > 0
    as_text = run(["evaluate", str(result_path), "--gt", str(occluded_input)])
    shown = printed_scores(as_text.stdout)
    assert shown["e3d_occluded_global"] == pytest.approx(expected["e3d_occluded_global"], abs=1e-4)
    assert "observed (frame, point) entries:" in as_text.stdout
    assert f"{100 * occlusion().mean():.1f} %" in as_text.stdout


def test_evaluate_takes_the_inputs_visibility_when_the_result_has_none(
    occluded_input, sequence, tmp_path
):
    # E.g. a result file written before visibility was stored, scored against the occluded input.
    stored = fake_solution(sequence, occlusion())
    result_path = write_result(tmp_path / "r.npz", dataclasses.replace(stored, visibility=None))
    scores = json.loads(
        run(["evaluate", str(result_path), "--gt", str(occluded_input), "--json"]).stdout
    )
    assert scores["observed_fraction"] == pytest.approx(occlusion().mean())


@pytest.mark.skipif(not SOLVER_TAKES_VISIBILITY, reason="the solver takes no visibility yet")
def test_reconstruct_of_occluded_tracks_end_to_end(occluded_input, tmp_path):
    output = tmp_path / "occluded.h5"
    outcome = run(["reconstruct", str(occluded_input), "-o", str(output), "-q"])
    assert outcome.exit_code == 0, outcome.output
    stored = read_result(output)
    np.testing.assert_array_equal(stored.visibility, occlusion())
    assert np.isfinite(stored.shapes).all() and stored.shapes.shape == (N_FRAMES, N_POINTS, 3)
    assert "e3D of the occluded entries" in outcome.stdout


# --------------------------------------------------------------------------------------------
# demo


def test_demo_writes_input_result_and_frames(tmp_path):
    out = tmp_path / "demo"
    outcome = run(["demo", "--points", "300", "--frames", "12", "--out", str(out), "-q"])
    assert outcome.exit_code == 0, outcome.output
    measurements = read_measurements(out / "input.npz")
    assert measurements.W.shape == (24, 300)
    for dataset in ("rotations", "ground_truth", "faces", "colors"):
        assert getattr(measurements, dataset) is not None
    stored = read_result(out / "result.npz")
    assert stored.shapes.shape == (12, 300, 3)
    assert stored.params.rotations in ("intersection", "windowed")  # what "auto" chose
    assert len(list((out / "ply").glob("*.ply"))) == 12
    expected = evaluate(
        stored.shapes, measurements.ground_truth, stored.rotations, measurements.rotations
    )
    shown = printed_scores(outcome.stdout)
    assert set(shown) == set(expected)
    for key, value in expected.items():
        assert shown[key] == pytest.approx(value, abs=0.006)
    assert expected["e3d_procrustes"] < 0.2  # 0.13 for these 12 frames; garbage is > 0.5
    assert f"moju evaluate {out / 'result.npz'} --gt {out / 'input.npz'}" in outcome.stdout


def test_demo_refuses_unusable_noise(tmp_path, solver_must_not_run):
    outcome = run(["demo", "--points", "50", "--noise", "inf", "--out", str(tmp_path / "d")])
    assert_clean_failure(outcome, 2, "noise")
    assert not (tmp_path / "d").exists()


def test_demo_runs_the_articulated_body_and_refuses_to_render_it(tmp_path, solver_must_not_run):
    refused = run(["demo", "--sequence", "body-turn", "--video", "--out", str(tmp_path / "v")])
    assert_clean_failure(refused, 2, "body-turn is markers")
    assert not (tmp_path / "v").exists()


def test_demo_solves_the_articulated_body(tmp_path):
    out = tmp_path / "body"
    arguments = ["demo", "--sequence", "body-osc", "--points", "20", "--frames", "60"]
    outcome = run([*arguments, "--out", str(out), "-q"])
    assert outcome.exit_code == 0, outcome.output
    measurements = read_measurements(out / "input.npz")
    assert measurements.W.shape == (120, 20) and measurements.faces is None
    assert len(list((out / "ply").glob("*.ply"))) == 60


def test_demo_default_size_is_the_documented_one():
    default = next(p for p in solver_commands.demo.params if p.name == "points").default
    assert default == solver_commands.DEMO_POINTS == 5_000


# --------------------------------------------------------------------------------------------
# the console script as a real process


def test_console_script_reconstructs(inputs, tmp_path):
    output, ply_dir = tmp_path / "result.hdf5", tmp_path / "ply"
    completed = subprocess.run(
        [*moju_command(), "reconstruct", str(inputs["full"]), "-o", str(output)]
        + ["--ply-dir", str(ply_dir)],
        capture_output=True,
        text=True,
        timeout=120,
        env=subprocess_environment(),
    )
    assert completed.returncode == 0, completed.stderr
    assert "iterating" in completed.stderr  # the progress bar goes to stderr ...
    assert "iterating" not in completed.stdout  # ... and the summary to stdout
    assert "e3D, per-frame Procrustes alignment" in completed.stdout
    stored = read_result(output)
    assert stored.shapes.shape == (N_FRAMES, N_POINTS, 3)
    # The bar ends on the shape gap, the one the stop reason is about.
    shown = re.findall(r"shape gap=(\S+?)\]", completed.stderr)
    assert shown and shown[-1] == f"{stored.history['gap_shape'][-1]:.1e}", completed.stderr
    assert len(list(ply_dir.glob("*.ply"))) == N_FRAMES


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_console_script_ctrl_c_exits_130_without_output(long_input, tmp_path):
    output = tmp_path / "result.npz"
    process = subprocess.Popen(
        [*moju_command(), "reconstruct", str(long_input), "-o", str(output), *LONG_RUN],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=subprocess_environment(),
        # Ctrl-C in a terminal: a test runner started in the background of a non-interactive
        # shell ignores SIGINT, its children inherit that, and Python then installs no
        # KeyboardInterrupt handler.
        preexec_fn=_default_sigint,
    )
    stderr = bytearray()

    def collect() -> None:
        while chunk := process.stderr.read1():
            stderr.extend(chunk)

    reader = threading.Thread(target=collect)
    reader.start()
    try:
        deadline = time.monotonic() + 60
        while b"iterating" not in stderr and time.monotonic() < deadline:
            time.sleep(0.05)
        assert b"iterating" in stderr, stderr.decode(errors="replace")
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=30) == 130
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        reader.join(timeout=10)
    text = stderr.decode(errors="replace")
    assert "Traceback" not in text
    assert "interrupted" in text
    assert list(tmp_path.iterdir()) == []  # neither the result nor a temporary file
