"""The RQ job function: load a job's input, run the solver, store the result, record the outcome.

Outcomes and what the user reads in the job's ``error``:

* solver finished: status ``finished``, result in ``<data_dir>/jobs/<id>/result.h5``;
* a video job runs a tracking stage first (progress stage ``tracking``, one report per
  frame at most every 0.5 s): its tracks go to ``tracks.npz`` and, as solver input, to
  ``input.npz``, with the camera of the job's ``focal`` or ``intrinsics`` field (K, as
  ``moju track --focal`` / ``--intrinsics`` stores it; without one the default camera of the
  frame size applies); a video the tracker cannot use fails the job with the tracker's
  message;
* the camera the solve used (if any) is recorded in the result's metadata (``intrinsics``:
  K and its origin, as ``moju reconstruct`` records it);
* the input cannot be used (:class:`moju_core.errors.MeasurementError`): ``failed`` with the
  solver's message verbatim;
* time limit (``MOJU_JOB_TIMEOUT``) exceeded: ``failed`` with "timed out: ..." and the limit;
* estimated memory above ``MOJU_WORKER_MEMORY_BYTES`` (the API refuses such jobs; a worker
  with a smaller limit than the API's refuses them too): ``failed`` with the estimate;
* anything else: ``failed`` with ``internal error: <type>: <message>``, and the traceback in
  the worker's log;
* cancelled (``DELETE``): the record already says ``cancelled``; the solver stops at its next
  progress report and the worker just leaves.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
import warnings
from collections.abc import Callable
from typing import Any
from uuid import UUID

import numpy as np
from redis.exceptions import ConnectionError as RedisConnectionError
from redis.exceptions import TimeoutError as RedisTimeoutError
from rq import get_current_job
from rq.timeouts import JobTimeoutException
from threadpoolctl import threadpool_limits

from moju_core import feasibility
from moju_core.cameras.intrinsics import Intrinsics
from moju_core.errors import Cancelled, MeasurementError
from moju_core.footage.tracking import (
    DEFAULT_STEP,
    TrackingProgress,
    solvable_tracks,
    track_video,
    tracks_measurements,
)
from moju_core.io import Measurements
from moju_core.params import rotation_method
from moju_core.result import Diagnostics, Progress, Result, Stage
from service.connection import connect_redis
from service.job_store import JobStore
from service.schemas import JobRecord
from service.settings import WORKER_MEMORY_SETTING, Settings, get_settings
from service.states import JobStatus
from service.storage import LocalStorage, Storage
from worker import rq_log
from worker.heartbeat import Heartbeat
from worker.progress import ProgressReporter

logger = logging.getLogger(__name__)


def run_reconstruction(job_id: str) -> dict[str, Any]:
    """RQ entry point (enqueued by reference as ``worker.jobs.run_reconstruction``).

    Parameters
    ----------
    job_id : str
        The job's UUID; its input and record were written by the API before enqueueing.

    Returns
    -------
    dict
        ``{"status": ...}`` and, for finished jobs, ``n_iter`` and ``stop_reason`` (kept by
        RQ as the job's return value, for operators).
    """
    settings = get_settings()
    rq_job = get_current_job()
    if rq_job is not None:
        connection = rq_job.connection
    else:  # called directly, outside a worker (debugging)
        connection = connect_redis(settings.require_redis_url())
    store = JobStore(connection, retention_seconds=settings.result_ttl)
    # The limit that applies is the one the API gave RQ when it enqueued the job.
    time_limit = rq_job.timeout if rq_job is not None and rq_job.timeout else None
    outcome = execute(
        UUID(job_id), store, LocalStorage(settings.data_dir), settings, time_limit=time_limit
    )
    if rq_job is not None:  # for RQ's log line of this job (worker.rq_log)
        rq_log.note_outcome(rq_job.id, str(outcome.get("status")))
    return outcome


def _summary(
    result: Result, caught: list[warnings.WarningMessage], tracking: dict[str, Any] | None
) -> dict[str, Any]:
    return {
        "tracking": tracking,
        "n_iter": int(result.n_iter),
        "stop_reason": str(result.stop_reason),
        "shape_gap": result.final_shape_gap,
        "exact_fit": result.exact_fit,
        "timings": {name: float(value) for name, value in result.timings.items()},
        "resolved_parameters": result.params.model_dump(mode="json"),
        # Distinct messages in order: a warning raised every iteration is shown once.
        "warnings": list(dict.fromkeys(str(w.message) for w in caught)),
        "completion": _completion(result.diagnostics),
    }


def _completion(diagnostics: Diagnostics | None) -> dict[str, Any] | None:
    """:class:`service.schemas.CompletionSummary` of a solve with hidden entries, else None."""
    if diagnostics is None or diagnostics.completion_rank is None:
        return None
    return {
        "rank": int(diagnostics.completion_rank),
        "exact": bool(diagnostics.exact_completion),
        "held_out_error": None
        if diagnostics.exact_completion
        else float(diagnostics.completion_unexplained or 0.0),
    }


def _final_progress(result: Result, reporter: ProgressReporter) -> dict[str, Any]:
    gaps = result.history.get("gap")
    last_gap = float(gaps[-1]) if gaps is not None and len(gaps) else None
    rhos = result.history.get("rho")
    last_rho = float(rhos[-1]) if rhos is not None and len(rhos) else None
    elapsed = reporter.last_progress.elapsed if reporter.last_progress else 0.0
    return {
        "stage": "finished",
        "iteration": int(result.n_iter),
        "max_iter": int(result.params.max_iter),
        "gap": last_gap,
        "rho": last_rho,
        "fraction": 1.0,
        "elapsed": float(result.timings.get("total", elapsed)),
        "eta": 0.0,
    }


def _tracking_callback(reporter: ProgressReporter, n_frames: int, started: float):
    """The tracker's callback: its progress as the job's stage ``tracking``."""

    def report(progress: TrackingProgress) -> bool:
        total = max(progress.n_frames or n_frames, progress.frame, 1)
        elapsed = time.perf_counter() - started
        eta = elapsed / progress.frame * (total - progress.frame) if progress.frame else None
        stage = Progress(
            stage=Stage.TRACKING,
            iteration=progress.frame,
            max_iter=total,
            gap=math.nan,
            rho=math.nan,
            fraction=progress.frame / total,
            elapsed=elapsed,
            eta=eta,
        )
        return reporter(stage)

    return report


def _form_camera(record: JobRecord, frame_size: tuple[int, int]) -> Intrinsics | None:
    """The camera the job's form gave for its video, for frames of ``frame_size``; None
    without one (the tracks then carry no K and readers take the default of their frame
    size, as with ``moju track`` without --focal)."""
    camera = record.input.camera
    if camera is None or camera.source == "default":
        return None
    if camera.source == "focal":
        return Intrinsics.from_focal(camera.K[0][0], frame_size)
    return Intrinsics(np.array(camera.K), "given")


def _track(
    record: JobRecord, storage: Storage, reporter: ProgressReporter, settings: Settings
) -> tuple[Measurements, dict[str, Any]]:
    """The tracking stage of a video job: tracks stored with the job's camera, returned as
    solver input."""
    import cv2  # the tracker's; only video jobs need it

    # OpenCV's own thread pool is outside threadpoolctl's reach: MOJU_WORKER_THREADS too.
    cv2.setNumThreads(settings.worker_threads)
    video, mask = storage.video_files(record.id)
    step = record.input.video.step if record.input.video is not None else DEFAULT_STEP
    started = time.perf_counter()
    tracks = track_video(
        video,
        mask=mask,
        step=step,
        limits=settings.video_limits,
        callback=_tracking_callback(reporter, record.input.frames, started),
    )
    seconds = time.perf_counter() - started
    camera = _form_camera(record, tracks.frame_size)
    if camera is not None:
        tracks = dataclasses.replace(tracks, intrinsics=camera)
    kept = solvable_tracks(tracks)
    storage.write_tracks(record.id, kept)
    measurements = tracks_measurements(kept)
    storage.write_input(record.id, measurements)
    logger.info(
        "job %s: tracked %d frames in %.1f s, %d of %d tracks kept",
        record.id,
        tracks.n_frames,
        seconds,
        kept.n_points,
        tracks.n_points,
    )
    summary = {
        "tracks": tracks.n_points,
        "reconstructed": kept.n_points,
        "fraction_kept": tracks.fraction_kept,
        "seconds": seconds,
    }
    return measurements, summary


def _solve(
    record: JobRecord, storage: Storage, reporter: ProgressReporter, settings: Settings
) -> tuple[Result, list[warnings.WarningMessage], dict[str, Any] | None, Intrinsics | None]:
    """Track (a video job) and solve; the result, the warnings, the tracking summary and the
    camera the solve used."""
    # The solver loads scikit-learn; only workers need it.
    from moju_core import reconstruct
    from moju_core.perspective import used_camera

    # BLAS/OpenMP threads per process (MOJU_WORKER_THREADS) for the tracker here, and for the
    # solver through threads= below: N worker processes x T threads should not exceed the
    # cores, or they slow each other down.
    with (
        threadpool_limits(limits=settings.worker_threads),
        warnings.catch_warnings(record=True) as caught,
    ):
        # The user sees the tracker's and solver's warnings in the job resource.
        warnings.simplefilter("always")
        tracking = None
        if record.input.format == "video":
            measurements, tracking = _track(record, storage, reporter, settings)
        else:
            measurements = storage.read_input(record.id)
        # The mask only when points are missing, the camera only when the input has one
        # (K, or a frame size: a video's tracks): other data take the call as before.
        masked = {} if measurements.visibility is None else {"visibility": measurements.visibility}
        camera = {} if measurements.intrinsics is None else {"intrinsics": measurements.intrinsics}
        result = reconstruct(
            measurements.W,
            record.parameters,
            rotations=_known_rotations(record, measurements.rotations),
            callback=reporter,
            threads=settings.worker_threads,
            **masked,
            **camera,
        )
    for warning in caught:
        logger.warning("job %s: %s", record.id, warning.message)
    camera = measurements.intrinsics
    return result, caught, tracking, None if camera is None else used_camera(camera, result)


def _known_rotations(record: JobRecord, uploaded: np.ndarray | None) -> np.ndarray | None:
    """The uploaded R when the job's rotation method uses it (the library's rule), else None:
    with an estimating method it is only the truth the download's scores compare with."""
    method = rotation_method(record.parameters.rotations, uploaded is not None)
    return uploaded if method == "known" else None


def _until_redis_answers(action: Callable[[], bool], patience: float, job_id: UUID) -> bool:
    """Run a final transition, retrying through a Redis outage of up to ``patience`` s.

    The result is already on disk when a job's outcome is recorded; a Redis restart at that
    moment must not turn a finished job into a lost one.
    """
    deadline = time.monotonic() + patience
    delay = 0.2
    while True:
        try:
            return action()
        except (RedisConnectionError, RedisTimeoutError) as exc:
            if time.monotonic() + delay > deadline:
                raise
            logger.warning("job %s: Redis did not answer (%s); retrying", job_id, exc)
            time.sleep(delay)
            delay = min(delay * 2, 5.0)


def _memory_problem(record: JobRecord, settings: Settings) -> str | None:
    return feasibility.memory_problem(
        record.input.frames,
        record.input.points,
        settings.worker_memory_bytes,
        limit_name=WORKER_MEMORY_SETTING,
    )


def execute(
    job_id: UUID,
    store: JobStore,
    storage: Storage,
    settings: Settings,
    *,
    time_limit: int | None = None,
) -> dict[str, Any]:
    """Run one job to its end and record the outcome; see the module docstring.

    ``time_limit`` is the job's RQ timeout in seconds, for the message when it is exceeded
    (default ``settings.job_timeout``). While the job runs, a :class:`Heartbeat` renews its
    lease; every outcome is recorded in the name of this attempt, so an attempt that was
    given up (its worker seemed lost) cannot overwrite the job's fate.
    """
    attempt = store.start(job_id, lease_seconds=settings.heartbeat_ttl)
    if attempt is None:
        status = store.status(job_id)
        logger.info("job %s: not started, it is %s", job_id, status.value if status else "gone")
        return {"status": status.value if status else "deleted"}
    record = store.get(job_id, reconcile_with_rq=False)
    if record is None:  # deleted between start and now
        return {"status": "deleted"}
    logger.info(
        "job %s: started (attempt %d, %d frames x %d points)",
        job_id,
        attempt,
        record.input.frames,
        record.input.points,
    )
    if attempt > 1:
        storage.discard_outputs(job_id)  # whatever the lost attempt may have left
    too_big = _memory_problem(record, settings)
    if too_big is not None:
        store.fail(job_id, too_big, attempt)
        logger.info("job %s: refused, %s", job_id, too_big)
        return {"status": JobStatus.FAILED.value}
    heartbeat = Heartbeat(
        store, job_id, attempt, interval=settings.heartbeat_interval, ttl=settings.heartbeat_ttl
    )
    with heartbeat:
        return _run_attempt(
            record, attempt, store, storage, settings, heartbeat, time_limit=time_limit
        )


def _run_attempt(
    record: JobRecord,
    attempt: int,
    store: JobStore,
    storage: Storage,
    settings: Settings,
    heartbeat: Heartbeat,
    *,
    time_limit: int | None,
) -> dict[str, Any]:
    job_id = record.id
    reporter = ProgressReporter(
        store, job_id, attempt=attempt, still_ours=lambda: not heartbeat.lost.is_set()
    )
    patience = settings.heartbeat_ttl
    started = time.monotonic()
    try:
        result, caught, tracking, camera = _solve(record, storage, reporter, settings)
        metadata = {"job_id": str(job_id), "input": record.input.model_dump(mode="json")}
        if camera is not None:
            metadata["intrinsics"] = camera.to_metadata()
        storage.write_result(job_id, result, metadata=metadata)
    except Cancelled:
        # Only a user's cancel ends the job here; a job queued again or failed by the
        # watchdog (or deleted) was taken from this attempt, which records nothing.
        if heartbeat.lost.is_set() or reporter.stopped_because is not JobStatus.CANCELLED:
            logger.info("job %s: attempt %d stopped, it no longer holds the job", job_id, attempt)
            return {"status": "superseded"}
        logger.info("job %s: stopped, it is %s", job_id, _status_text(reporter.stopped_because))
        return {"status": JobStatus.CANCELLED.value}
    except MeasurementError as exc:
        message = str(exc)
        if not _until_redis_answers(lambda: store.fail(job_id, message, attempt), patience, job_id):
            # Cancelled meanwhile: that is the outcome.
            return {"status": JobStatus.CANCELLED.value}
        logger.info("job %s: failed on its input: %s", job_id, message)
        return {"status": JobStatus.FAILED.value}
    except JobTimeoutException:
        limit = time_limit or settings.job_timeout
        store.fail(
            job_id,
            f"timed out: the job ran longer than this server's limit of {limit} s "
            "(MOJU_JOB_TIMEOUT) and was stopped: lower max_iter, subsample the points, or "
            "ask the operator to raise the limit",
            attempt,
        )
        raise  # RQ records the timeout in its failed registry too
    except Exception as exc:
        if store.status(job_id) is not JobStatus.RUNNING or heartbeat.lost.is_set():
            # Cancelled or deleted while we were at it (e.g. the files vanished under us).
            logger.info("job %s: ended by the user during %s", job_id, type(exc).__name__)
            return {"status": JobStatus.CANCELLED.value}
        logger.exception("job %s: internal error", job_id)
        store.fail(job_id, f"internal error: {type(exc).__name__}: {exc}", attempt)
        raise
    summary, final = _summary(result, caught, tracking), _final_progress(result, reporter)
    solved_input = None
    if tracking is not None:
        # The upload's figures were estimates (grid points on the mask, all observed): the
        # job now says what was tracked and solved.
        solved_input = record.input.model_copy(
            update={
                "points": int(result.shapes.shape[1]),
                "observed_fraction": (
                    1.0 if result.visibility is None else float(np.mean(result.visibility))
                ),
            }
        )
    if not _until_redis_answers(
        lambda: store.finish(job_id, summary, final, attempt, input_summary=solved_input),
        patience,
        job_id,
    ):
        status = store.status(job_id)
        if status in (JobStatus.FAILED, JobStatus.QUEUED):
            # This attempt was given up while it finished: its result must not outlive it.
            storage.discard_outputs(job_id)
        # Cancelled after the result was written: the API deletes the files.
        logger.info("job %s: finished but it is %s now", job_id, _status_text(status))
        return {"status": status.value if status else "deleted"}
    logger.info(
        "job %s: finished in %.2f s (%d iterations, %s)",
        job_id,
        time.monotonic() - started,
        result.n_iter,
        result.stop_reason,
    )
    return {
        "status": JobStatus.FINISHED.value,
        "n_iter": int(result.n_iter),
        "stop_reason": str(result.stop_reason),
    }


def _status_text(status: JobStatus | None) -> str:
    return status.value if status is not None else "deleted"
