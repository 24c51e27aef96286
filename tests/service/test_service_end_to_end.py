"""End to end: the API over real sockets, real worker processes, a real Redis.

Each test starts its own worker (``python -m worker``, RQ's forking worker) against the
flushed test Redis and a fresh data directory.
"""

from __future__ import annotations

import io
import json
import os
import signal
import threading
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from redis import Redis
from rq.job import Job as RQJob
from service_testing import (
    LONG_PARAMS,
    collapsed_tracks,
    measurements_of,
    running_worker,
    wait_for,
)
from threadpoolctl import threadpool_limits

from moju_core import reconstruct
from moju_core.io import read_result, write_measurements
from moju_core.params import SolverParams
from moju_core.ply import read_ply_points
from service.app import create_app
from service.client import JobFailed, MojuClient
from service.job_store import record_key
from service.processes import children_of, signal_until_exit
from service.schemas import JobResource
from service.settings import Settings
from service.states import JobStatus
from worker.progress import REPORT_INTERVAL
from worker.runner import INTERRUPTED

# About 1500 iterations of a 300-point problem: a few seconds here, and never too short for
# the paced reports of test_upload_run_follow_download_delete (each step lets the work horse
# run for a few milliseconds only).
WATCHABLE_PARAMS = {"max_iter": 1500, "tol": 0.0, "rho_growth": 1.01, "rho_max": 1e12}
#: Progress reports the test draws out of the running job, one at a time.
PACED_REPORTS = 3


def _progress(redis_client: Redis, job_id) -> dict:
    raw = redis_client.hget(record_key(job_id), "progress")
    return json.loads(raw) if raw else {}


def _pace_progress(
    redis_client: Redis, worker, job_id, streamed: Callable[[int], bool], paced: list[int]
) -> None:
    """Draw PACED_REPORTS progress reports out of the running job, one at a time.

    The work horse is held stopped (SIGSTOP) while the event stream catches up, so the test
    counts reports the job made rather than reports a sampling stream happened to catch: how
    fast the machine solves does not matter. The horse is stopped as soon as it iterates;
    after each report has been streamed, and at least REPORT_INTERVAL after the previous
    report (so that the next call of its progress callback reports), it is continued until
    its record shows a new iteration, then stopped again.
    """
    horses: list[int] = []

    def signal_horses(signum: int) -> None:
        for horse in horses:
            os.kill(horse, signum)

    try:
        wait_for(lambda: _progress(redis_client, job_id).get("stage") == "iterating",
                 timeout=60, interval=0.002, message="the job to iterate")  # fmt: skip
        horses.extend(children_of(worker.process.pid))
        signal_horses(signal.SIGSTOP)
        paced.append(_progress(redis_client, job_id)["iteration"])
        for _ in range(PACED_REPORTS):
            wait_for(lambda: streamed(paced[-1]), timeout=30, message="the report on the stream")
            time.sleep(REPORT_INTERVAL)  # a lower bound: the next callback is due
            signal_horses(signal.SIGCONT)
            wait_for(lambda: _progress(redis_client, job_id)["iteration"] > paced[-1],
                     timeout=30, interval=0.002, message="the next report")  # fmt: skip
            signal_horses(signal.SIGSTOP)
            paced.append(_progress(redis_client, job_id)["iteration"])
        wait_for(lambda: streamed(paced[-1]), timeout=30, message="the last paced report")
    finally:
        signal_horses(signal.SIGCONT)


def test_upload_run_follow_download_delete(
    live_api: str,
    worker,
    input_file: Path,
    small_sequence,
    settings: Settings,
    tmp_path: Path,
    redis_client: Redis,
) -> None:
    seen: list[JobResource] = []

    def streamed(iteration: int) -> bool:
        return any(
            event.progress and event.progress.stage == "iterating"
            and event.progress.iteration == iteration
            for event in list(seen)
        )  # fmt: skip

    with MojuClient(live_api) as client:
        job = client.submit(input_file, WATCHABLE_PARAMS)
        assert job.status is JobStatus.QUEUED
        paced: list[int] = []
        pacer = threading.Thread(
            target=_pace_progress, args=(redis_client, worker, job.id, streamed, paced)
        )
        pacer.start()
        try:
            finished = client.wait(job.id, on_progress=seen.append, timeout=120)
        finally:
            pacer.join(timeout=120)
        assert len(paced) == PACED_REPORTS + 1, paced

        # queued -> running with advancing progress -> finished, as seen on the event stream.
        statuses = [event.status for event in seen]
        assert statuses[-1] is JobStatus.FINISHED
        assert set(statuses) <= {JobStatus.QUEUED, JobStatus.RUNNING, JobStatus.FINISHED}
        iterating = [
            e.progress.iteration
            for e in seen
            if e.status is JobStatus.RUNNING and e.progress and e.progress.stage == "iterating"
        ]
        # Every paced report was streamed, in order, among whatever else the stream caught.
        assert [i for i in iterating if i in paced] == paced, (paced, iterating)
        assert paced == sorted(set(paced))
        assert iterating == sorted(iterating) and iterating[0] < iterating[-1]
        assert finished.progress.fraction == 1.0 and finished.progress.stage == "finished"
        assert finished.started_at is not None
        assert finished.created_at <= finished.started_at <= finished.ended_at
        assert finished.result.n_iter == 1500 and finished.result.stop_reason == "max_iter"

        # The result equals the solver's output for the same input and parameters.
        client.download(job.id, tmp_path / "result.npz")
        client.download(job.id, tmp_path / "result.h5")
        with threadpool_limits(limits=1):  # as in the worker (MOJU_WORKER_THREADS=1)
            expected = reconstruct(
                small_sequence.W,
                SolverParams(**WATCHABLE_PARAMS),
                rotations=small_sequence.rotations,
            )
        with np.load(tmp_path / "result.npz") as npz:
            np.testing.assert_allclose(npz["shapes"], expected.shapes, rtol=0, atol=1e-9)
            np.testing.assert_allclose(npz["rotations"], expected.rotations, rtol=0, atol=1e-9)
            assert npz["shapes"].shape == (10, 300, 3)
        from_h5 = read_result(tmp_path / "result.h5")
        np.testing.assert_array_equal(from_h5.shapes, np.load(tmp_path / "result.npz")["shapes"])
        assert from_h5.metadata["job_id"] == str(job.id)

        # One frame as PLY: P vertices, the frame's shape (stored as float32).
        points = read_ply_points(client.frame_ply(job.id, 4))
        assert points.shape == (300, 3)
        np.testing.assert_allclose(points, expected.shapes[4], rtol=1e-6, atol=1e-6)

        # All frames as a zip of PLY files.
        client.download_frames_zip(job.id, tmp_path / "frames.zip")
        with zipfile.ZipFile(tmp_path / "frames.zip") as archive:
            names = archive.namelist()
            assert names == [f"frame_{f:04d}.ply" for f in range(10)]
            last = read_ply_points(io.BytesIO(archive.read(names[-1])))
            np.testing.assert_allclose(last, expected.shapes[-1], rtol=1e-6, atol=1e-6)

        # Metrics against the uploaded ground truth and rotations.
        metrics = client.metrics(job.id)
        assert 0 <= metrics.e3d_procrustes <= metrics.e3d_global
        assert metrics.e3d_procrustes < 0.3
        assert metrics.rotation_error_deg is not None

        # Listed, then deleted with its files.
        listed = client.list_jobs()
        assert [item.id for item in listed.items] == [job.id]
        client.cancel(job.id)
        assert not (settings.data_dir / "jobs" / str(job.id)).exists()
        assert client.list_jobs().total == 0


def test_running_job_is_cancelled_at_its_next_iteration(
    client: TestClient, worker, long_sequence, tmp_path: Path, redis_client: Redis, settings
) -> None:
    path = write_measurements(tmp_path / "long.npz", measurements_of(long_sequence, extras=False))
    files = {"file": (path.name, path.read_bytes())}
    job = client.post("/v1/jobs", files=files, data={"params": json.dumps(LONG_PARAMS)}).json()
    url = f"/v1/jobs/{job['id']}"

    def iterating():
        current = client.get(url).json()
        progress = current["progress"] or {}
        return current["status"] == "running" and progress.get("iteration", 0) >= 5

    wait_for(iterating, timeout=30, message="the job to iterate")
    cancelled_at = time.monotonic()
    assert client.delete(url).status_code == 204
    assert client.get(url).json()["status"] == "cancelled"

    # The work horse returns promptly: RQ sees the function end.
    rq_job = RQJob.fetch(job["id"], connection=redis_client)
    wait_for(lambda: rq_job.get_status() == "finished", timeout=10, message="the horse to stop")
    assert time.monotonic() - cancelled_at < 10.0  # with slack for a loaded machine
    final = client.get(url).json()
    assert final["status"] == "cancelled"
    assert final["progress"]["iteration"] < LONG_PARAMS["max_iter"]
    assert not (settings.data_dir / "jobs" / job["id"]).exists()
    assert "stopped, it is cancelled" in worker.log()
    # RQ's own line about the job says how it ended, not "Job OK" (worker.rq_log).
    assert f"Job ended, cancelled ({job['id']})" in worker.log()
    assert f"Job OK ({job['id']})" not in worker.log()

    # The worker is free again: a small job runs to the end.
    small = client.post(
        "/v1/jobs", json={"tracks": long_sequence.W[:20, :200].reshape(10, 2, 200)
                          .transpose(0, 2, 1).tolist(), "params": {"max_iter": 20}},
    ).json()  # fmt: skip
    wait_for(
        lambda: client.get(f"/v1/jobs/{small['id']}").json()["status"] == "finished",
        timeout=30,
        message="the next job to finish",
    )
    # ... and RQ calls that one OK, as it was.
    wait_for(lambda: f"Job OK ({small['id']})" in worker.log(), timeout=10, message="Job OK")


def test_solver_refusal_is_reported_verbatim(live_api: str, worker) -> None:
    with MojuClient(live_api) as client:
        job = client.submit_tracks(collapsed_tracks(), {"max_iter": 10})
        with pytest.raises(JobFailed) as failure:
            client.wait(job.id, timeout=60)
    failed = failure.value.job
    assert failed.status is JobStatus.FAILED
    assert failed.error == "W is zero after centring: the points do not move in the image"
    assert failed.ended_at is not None


def test_unexpected_error_is_an_internal_error_with_traceback_in_log(
    settings: Settings, input_file: Path, tmp_path: Path
) -> None:
    with TestClient(create_app(settings)) as client:
        files = {"file": (input_file.name, input_file.read_bytes())}
        job = client.post("/v1/jobs", files=files, data={"params": '{"max_iter": 5}'}).json()
        # A directory where the result file belongs makes the final rename fail.
        (settings.data_dir / "jobs" / job["id"] / "result.h5").mkdir()
        with running_worker(settings, tmp_path / "worker.log") as worker:
            wait_for(
                lambda: client.get(f"/v1/jobs/{job['id']}").json()["status"] == "failed",
                timeout=30,
                message="the job to fail",
            )
            log = worker.log()
        failed = client.get(f"/v1/jobs/{job['id']}").json()
    assert failed["error"].startswith("internal error: IsADirectoryError: ")
    assert "Traceback (most recent call last)" in log and "IsADirectoryError" in log


def test_job_over_the_time_limit_fails_with_the_limit(
    settings: Settings, long_sequence, tmp_path: Path
) -> None:
    short = settings.model_copy(update={"job_timeout": 2})
    path = write_measurements(tmp_path / "long.npz", measurements_of(long_sequence, extras=False))
    with TestClient(create_app(short)) as client:
        with running_worker(short, tmp_path / "worker.log"):
            files = {"file": (path.name, path.read_bytes())}
            job = client.post("/v1/jobs", files=files, data={"params": json.dumps(LONG_PARAMS)})
            url = f"/v1/jobs/{job.json()['id']}"
            failed = wait_for(
                lambda: (r := client.get(url).json())["status"] == "failed" and r,
                timeout=30,
                message="the job to time out",
            )
            # The worker is free again: the next job runs to the end.
            small = client.post("/v1/jobs", json={"tracks": collapsed_tracks().tolist()}).json()
            ran = wait_for(
                lambda: (
                    (r := client.get(f"/v1/jobs/{small['id']}").json())["status"] == "failed" and r
                ),
                timeout=30,
                message="the next job to be run",
            )
            assert ran["error"].startswith("W is zero after centring")  # the solver's verdict
    assert failed["error"].startswith("timed out: ")
    assert "longer than this server's limit of 2 s (MOJU_JOB_TIMEOUT)" in failed["error"]
    assert not (short.data_dir / "jobs" / failed["id"] / "result.h5").exists()


def test_worker_shutdown_marks_its_running_job_interrupted(
    settings: Settings, long_sequence, tmp_path: Path
) -> None:
    path = write_measurements(tmp_path / "long.npz", measurements_of(long_sequence, extras=False))
    with TestClient(create_app(settings)) as client:
        with running_worker(settings, tmp_path / "worker.log") as worker:
            files = {"file": (path.name, path.read_bytes())}
            job = client.post("/v1/jobs", files=files, data={"params": json.dumps(LONG_PARAMS)})
            url = f"/v1/jobs/{job.json()['id']}"
            wait_for(lambda: client.get(url).json()["status"] == "running", timeout=30)
            # Warm shutdown, then cold shutdown (repeated until the worker exits). Generous:
            # on a machine running other solves, the cold shutdown (the horse killed, the job
            # recorded) took more than 15 s.
            signal_until_exit([worker.process], timeout=60)
        final = client.get(url).json()
    assert final["status"] == "failed"
    assert final["error"] == INTERRUPTED


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_killed_work_horse_is_reported_as_failed(
    client: TestClient, worker, long_sequence, tmp_path: Path
) -> None:
    """What an out-of-memory kill looks like: the horse dies without recording anything."""
    path = write_measurements(tmp_path / "long.npz", measurements_of(long_sequence, extras=False))
    files = {"file": (path.name, path.read_bytes())}
    job = client.post("/v1/jobs", files=files, data={"params": json.dumps(LONG_PARAMS)}).json()
    url = f"/v1/jobs/{job['id']}"
    wait_for(lambda: client.get(url).json()["status"] == "running", timeout=30)
    horses = wait_for(lambda: children_of(worker.process.pid), timeout=10, message="the horse")
    for horse in horses:
        os.kill(horse, signal.SIGKILL)

    failed = wait_for(
        lambda: (r := client.get(url).json())["status"] == "failed" and r,
        timeout=20,
        message="the job to be reported failed",
    )
    assert failed["error"].startswith("the worker running this job stopped before recording")
    assert "signal 9" in failed["error"]
