"""The job function run in-process on a real Redis and a real data directory."""

from __future__ import annotations

import threading
import time
import warnings

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from moju_core import reconstruct
from moju_core.datasets import make_sequence
from moju_core.params import SolverParams
from moju_core.validation import tracks_to_W
from service.states import JobStatus
from worker.jobs import execute

LONG = SolverParams(max_iter=10_000, tol=0.0, rho_growth=1.0005, rho_max=1e12)


def test_finished_job_stores_result_and_summary(store, storage, settings, add_job, face_W):
    params = SolverParams(max_iter=30, seed=2)
    job_id = add_job(face_W, params)

    outcome = execute(job_id, store, storage, settings)

    assert outcome == {"status": "finished", "n_iter": 30, "stop_reason": "max_iter"}
    record = store.get(job_id, reconcile_with_rq=False)
    assert record.status is JobStatus.FINISHED
    assert record.started_at <= record.ended_at
    assert record.progress.stage == "finished" and record.progress.fraction == 1.0
    assert record.result.n_iter == 30
    assert record.result.resolved_parameters.n_groups is not None  # derived defaults filled
    stored = storage.read_result(job_id)
    with threadpool_limits(limits=1), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        expected = reconstruct(face_W, params)
    np.testing.assert_allclose(stored.shapes, expected.shapes, rtol=0, atol=1e-9)
    # The end of the loop as the CLI describes it: the last shape gap and whether it fitted
    # the tracks exactly (noise-free tracks stop at that fit's precision).
    assert record.result.shape_gap == expected.final_shape_gap > 0
    assert record.result.exact_fit is expected.exact_fit
    assert record.result.completion is None  # nothing was hidden
    # The solver's warnings reach the user, each once.
    assert record.result.warnings == list(dict.fromkeys(str(w.message) for w in caught))
    assert stored.metadata["job_id"] == str(job_id)
    # Finished records expire with the retention period.
    assert 0 < store.connection.ttl(f"moju:job:{job_id}") <= settings.result_ttl


def test_a_job_with_missing_points_says_how_they_were_completed(
    store, storage, settings, add_job, face_W
):
    W = face_W.copy()
    W[6:10, 100:160] = np.nan  # points 100-159 hidden in frames 3 and 4
    params = SolverParams(max_iter=30, seed=2)
    job_id = add_job(W, params)
    assert execute(job_id, store, storage, settings)["status"] == "finished"
    completion = store.get(job_id, reconcile_with_rq=False).result.completion
    with threadpool_limits(limits=1), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        expected = reconstruct(W, params).diagnostics
    assert completion.rank == expected.completion_rank >= 1
    assert completion.exact is expected.exact_completion is False  # 10 frames: not tried
    assert completion.held_out_error == pytest.approx(expected.completion_unexplained)


def test_measurement_error_fails_the_job_with_the_message(
    store, storage, settings, add_job
) -> None:
    job_id = add_job(tracks_to_W(np.full((5, 20, 2), 3.0)))
    outcome = execute(job_id, store, storage, settings)
    assert outcome == {"status": "failed"}
    record = store.get(job_id, reconcile_with_rq=False)
    assert record.status is JobStatus.FAILED
    assert record.error == "W is zero after centring: the points do not move in the image"
    assert not storage.has_result(job_id)


def test_job_cancelled_while_queued_is_not_run(store, storage, settings, add_job, face_W):
    job_id = add_job(face_W)
    store.cancel(job_id)
    assert execute(job_id, store, storage, settings) == {"status": "cancelled"}
    record = store.get(job_id, reconcile_with_rq=False)
    assert record.status is JobStatus.CANCELLED and record.started_at is None


def test_job_cancelled_while_running_stops_promptly(store, storage, settings, add_job, long_W):
    job_id = add_job(long_W, LONG)
    outcome: dict = {}
    runner = threading.Thread(
        target=lambda: outcome.update(execute(job_id, store, storage, settings))
    )
    runner.start()
    deadline = time.monotonic() + 30
    while True:
        record = store.get(job_id, reconcile_with_rq=False)
        if record.progress is not None and record.progress.iteration >= 3:
            break
        assert time.monotonic() < deadline, "the job never started iterating"
        time.sleep(0.02)
    cancelled_at = time.monotonic()
    store.cancel(job_id)
    runner.join(timeout=10)
    assert not runner.is_alive()
    assert time.monotonic() - cancelled_at < 5.0  # next iteration, with slack for load
    assert outcome == {"status": "cancelled"}
    record = store.get(job_id, reconcile_with_rq=False)
    assert record.status is JobStatus.CANCELLED
    assert record.progress.iteration < LONG.max_iter
    assert not storage.has_result(job_id)


def test_worker_refuses_a_job_over_its_memory_limit(store, storage, settings, add_job, face_W):
    """The API refuses such jobs; a worker with a lower limit than the API's does too."""
    small = settings.model_copy(update={"worker_memory_bytes": 100 * 2**20})
    job_id = add_job(face_W)
    assert execute(job_id, store, storage, small) == {"status": "failed"}
    record = store.get(job_id, reconcile_with_rq=False)
    assert record.status is JobStatus.FAILED
    assert record.error == (
        "10 frames x 300 points would need about 129 MiB to solve; the limit is 100 MiB per "
        "job (MOJU_WORKER_MEMORY_BYTES): subsample the points or frames"
    )
    assert not storage.has_result(job_id)


def test_missing_points_reach_the_solver_and_the_stored_result(
    store, storage, settings, add_job, face_W, monkeypatch
):
    import moju_core.solver
    from moju_core.result import Result
    from moju_core.validation import with_missing

    visibility = np.ones((10, 300), dtype=bool)
    visibility[3:6, :50] = False
    calls = []

    def solver(W, params, *, rotations=None, callback=None, visibility=None, threads=None):
        calls.append((W, visibility))
        return Result(
            shapes=np.zeros((10, 300, 3)),
            rotations=np.tile(np.eye(3)[:2], (10, 1, 1)),
            labels=np.zeros(300, dtype=np.int64),
            history={},
            timings={"total": 0.0},
            params=params,
            n_iter=0,
            stop_reason="converged",
            scale=1.0,
            visibility=visibility,
        )

    monkeypatch.setattr(moju_core.solver, "reconstruct", solver)
    job_id = add_job(with_missing(face_W, visibility))
    assert execute(job_id, store, storage, settings)["status"] == "finished"
    ((W, given),) = calls
    np.testing.assert_array_equal(given, visibility)
    assert np.isnan(W[6:12, :50]).all() and np.isfinite(W[:6]).all()
    np.testing.assert_array_equal(storage.read_result(job_id).visibility, visibility)


@pytest.mark.parametrize("threads", [1, 2])
def test_worker_threads_setting_applies_inside_the_solve(
    store, storage, settings, add_job, face_W, monkeypatch, threads
):
    import moju_core.solver

    solve, seen = moju_core.solver.reconstruct, set()

    def recording(*args, callback, **kwargs):
        def inside(progress):
            if progress.stage == "iterating":
                seen.update(p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas")
            return callback(progress)

        return solve(*args, callback=inside, **kwargs)

    monkeypatch.setattr(moju_core.solver, "reconstruct", recording)
    job_id = add_job(face_W, SolverParams(max_iter=3))
    configured = settings.model_copy(update={"worker_threads": threads})
    # Whatever the process's limit was: MOJU_WORKER_THREADS decides.
    with threadpool_limits(limits=3 - threads):
        assert execute(job_id, store, storage, configured)["status"] == "finished"
    assert seen == {threads}


def test_uploaded_rotations_follow_the_librarys_rule(store, storage, settings, add_job, face_W):
    """Unset: the uploaded R is used, as by reconstruct() and ``moju reconstruct``; with an
    estimating method it is not, and the job's rotations are the library's estimate."""
    truth = make_sequence("face1", n_points=300).rotations
    default = add_job(face_W, SolverParams(max_iter=3), rotations=truth)
    auto = add_job(face_W, SolverParams(max_iter=3, rotations="auto"), rotations=truth)
    for job_id in (default, auto):
        assert execute(job_id, store, storage, settings)["status"] == "finished"
    np.testing.assert_allclose(storage.read_result(default).rotations, truth, atol=1e-12)
    record = store.get(default, reconcile_with_rq=False)
    assert record.result.resolved_parameters.rotations == "known"
    with threadpool_limits(limits=1):
        expected = reconstruct(face_W, SolverParams(max_iter=3, rotations="auto"))
    np.testing.assert_allclose(storage.read_result(auto).rotations, expected.rotations, atol=1e-9)
    record = store.get(auto, reconcile_with_rq=False)
    assert record.result.resolved_parameters.rotations == expected.params.rotations


@pytest.mark.parametrize("requested", [None, "auto"])
def test_same_file_gives_the_same_rotations_from_the_cli_and_a_job(
    store, storage, settings, add_job, face_W, tmp_path, requested
):
    from click.testing import CliRunner

    from moju_cli.main import cli
    from moju_core.io import Measurements, read_result, write_measurements

    truth = make_sequence("face1", n_points=300).rotations
    source = write_measurements(tmp_path / "in.npz", Measurements(W=face_W, rotations=truth))
    chosen = [] if requested is None else ["--rotations", requested]
    output = tmp_path / "cli.npz"
    args = ["reconstruct", str(source), "-o", str(output), "-q", "--max-iter", "3", *chosen]
    outcome = CliRunner().invoke(cli, args)
    assert outcome.exit_code == 0, outcome.output
    params = SolverParams(max_iter=3, **({} if requested is None else {"rotations": requested}))
    job_id = add_job(face_W, params, rotations=truth)
    assert execute(job_id, store, storage, settings)["status"] == "finished"
    from_cli, from_job = read_result(output), storage.read_result(job_id)
    np.testing.assert_allclose(from_job.rotations, from_cli.rotations, rtol=0, atol=1e-12)
    resolved = store.get(job_id, reconcile_with_rq=False).result.resolved_parameters.rotations
    assert resolved == from_cli.params.rotations
    assert (resolved == "known") is (requested is None)
