"""Routes of the job resource: submit, read, list, follow (server-sent events), delete."""

from __future__ import annotations

import json
import logging
import time
from collections.abc import AsyncIterator
from datetime import datetime, timezone
from typing import Annotated, Any
from uuid import UUID, uuid4

import anyio
import anyio.to_thread
from fastapi import APIRouter, Depends, Query, Request, Response, status
from fastapi.responses import StreamingResponse

from moju_core.params import SolverParams
from service import queueing
from service.deps import Caller, JobId, Services, ServicesDep, get_caller
from service.errors import JobNotFound, TooManyJobs
from service.schemas import (
    ErrorBody,
    JobLinks,
    JobList,
    JobRecord,
    JobResource,
    TracksBody,
)
from service.states import JobStatus
from service.uploads import Submission, read_submission

logger = logging.getLogger(__name__)

#: Documented on every /v1 route; only sent when the server has API keys.
UNAUTHORIZED = {
    401: {
        "model": ErrorBody,
        "description": "This server needs an API key and the request has no valid one.",
    }
}

router = APIRouter(
    prefix="/v1/jobs", tags=["jobs"], dependencies=[Depends(get_caller)], responses=UNAUTHORIZED
)

#: Largest offset of the job list (Redis ranges are 64-bit; no list is this long).
MAX_OFFSET = 1_000_000_000

#: Seconds a client refused for having too many queued jobs is told to wait (Retry-After).
RETRY_AFTER_SECONDS = 10

#: Seconds between two looks at a job while streaming its events; progress is reported by
#: workers at most every 0.5 s, so polling twice as often shows every report.
EVENT_POLL_SECONDS = 0.25
#: Seconds of silence after which the event stream sends a comment, so that proxies and
#: clients do not take a long quiet stage for a dead connection.
EVENT_KEEPALIVE_SECONDS = 15.0

_EXAMPLE_ID = "0b7e9f6c-3a51-4f0e-9d7c-2c1e8a4b5d60"
_NOT_FOUND = {"model": ErrorBody, "description": "No such job (or not a job id)."}


def job_resource(record: JobRecord) -> JobResource:
    """The record plus the links of the job's other resources."""
    base = f"/v1/jobs/{record.id}"
    links = JobLinks(
        self=base,
        events=f"{base}/events",
        result=f"{base}/result?format=h5",
        frames_zip=f"{base}/frames.zip",
        metrics=f"{base}/metrics" if record.input.has_ground_truth else None,
        tracks=f"{base}/tracks.npz" if record.input.format == "video" else None,
    )
    return JobResource(**dict(record), links=links)


def load_record(services: Services, job_id: UUID, owner: str) -> JobRecord:
    """The caller's job, or :class:`JobNotFound` (blocking: for ``def`` routes).

    Another key's job is not found either: callers cannot even learn that it exists.
    """
    record = services.store.get(job_id, owner=owner)
    if record is None or record.owner != owner:
        raise JobNotFound(job_id)
    return record


async def load_record_async(services: Services, job_id: UUID, owner: str) -> JobRecord:
    """:func:`load_record` for ``async def`` routes."""
    record = await services.store.get_async(job_id, owner)
    if record is None or record.owner != owner:
        raise JobNotFound(job_id)
    return record


def _reserve_slot(services: Services, record: JobRecord) -> None:
    limit = services.settings.max_queued_jobs_per_key
    if services.store.reserve(record.owner, record.id, limit):
        return
    whose = "this API key has" if record.owner else "this server has"
    logger.info("refused a job of %s: %d jobs active", record.owner or "anonymous", limit)
    raise TooManyJobs(
        f"{whose} {limit} jobs queued or running, the most allowed "
        f"(MOJU_MAX_QUEUED_JOBS_PER_KEY); wait until some end (or cancel some) and submit "
        f"again in {RETRY_AFTER_SECONDS} s",
        retry_after=RETRY_AFTER_SECONDS,
    )


def _store_and_enqueue(services: Services, record: JobRecord, submission: Submission) -> None:
    """Take a queue slot, write the input (or move the video in), then the record and the
    queue entry in one Redis transaction. Nothing is left behind when any step fails."""
    _reserve_slot(services, record)
    try:
        services.storage.create(record.id)
    except BaseException:
        services.store.release(record.owner, record.id)
        raise
    try:
        _write_upload(services, record, submission)
        with services.redis.pipeline(transaction=True) as pipe:
            pipe.multi()  # explicit MULTI first: RQ adds its commands to an open transaction
            services.store.add(record, pipe)
            queueing.enqueue_reconstruction(services.redis, services.settings, record.id, pipe)
            pipe.execute()
    except BaseException:
        services.storage.delete(record.id)
        try:
            services.store.release(record.owner, record.id)
        except Exception:  # Redis is down: the slot is reclaimed later (JobStore.reserve)
            logger.warning("job %s: could not give back its queue slot", record.id)
        raise


def _write_upload(services: Services, record: JobRecord, submission: Submission) -> None:
    video = submission.video
    if video is not None:
        services.storage.write_video(record.id, video.video, video.mask, video.first_frame)
    elif submission.staged_input is not None:
        services.storage.move_input(record.id, submission.staged_input)
    else:  # read_submission gives one or the other
        raise ValueError("a submission holds measurements or a video")


_SUBMIT_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "description": (
            "Either a measurement file (multipart/form-data) or, for small inputs, the tracks "
            "as JSON. The body may not exceed MOJU_MAX_UPLOAD_BYTES (a JSON body "
            "MOJU_MAX_JSON_BYTES), and must keep arriving: a pause of MOJU_BODY_TIMEOUT "
            "seconds drops it with 408."
        ),
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": ["file"],
                    "properties": {
                        "file": {
                            "type": "string",
                            "format": "binary",
                            "description": (
                                "npz or HDF5 with W (2F x P) or tracks (F x P x 2), NaN "
                                "(x and y) where a point is not observed in a frame, and "
                                "optional visibility (F x P bool, true = observed; must "
                                "agree with the NaN), R, gt, faces, colors; or CSV with "
                                "header frame,point,x,y, one row per observed point and "
                                "frame (a missing row is an unobserved point). Every point "
                                "must be observed in 2 frames or more, every frame must "
                                "observe 3 points or more. Or a video (mp4, webm or avi, "
                                "recognised by its content; at most MOJU_MAX_VIDEO_BYTES, "
                                "MOJU_MAX_VIDEO_WIDTH x MOJU_MAX_VIDEO_HEIGHT pixels, "
                                "MOJU_MAX_VIDEO_FRAMES frames and MOJU_MAX_VIDEO_SECONDS): "
                                "the job then tracks it (every frame, a grid every 4 pixels "
                                "on the object) before the solve."
                            ),
                        },
                        "mask": {
                            "type": "string",
                            "format": "binary",
                            "description": (
                                "With a video only: PNG of the first frame's size whose "
                                "non-zero pixels (or alpha) mark the object to track. "
                                "Without one the textured region of the first frame is "
                                "tracked."
                            ),
                        },
                        "params": {
                            "type": "string",
                            "description": "Solver parameters as a JSON object (SolverParams).",
                            "example": '{"max_iter": 100, "seed": 1}',
                        },
                        "focal": {
                            "type": "string",
                            "description": (
                                "The camera's focal length in pixels (a positive number), "
                                "with the principal point at the image centre ((width - 1) "
                                "/ 2, (height - 1) / 2): needs the frame size, a video's or "
                                "the frame_size of a tracks file. Not with 'intrinsics'. "
                                "Without either, a video gets the default camera (focal "
                                "length 1.2 x the larger image side, which the solve replaces "
                                "by the focal length it estimates from the tracks where they "
                                "tell: the result's metadata 'intrinsics' records the camera "
                                "used) and a tracks file keeps its own K."
                            ),
                            "example": "800",
                        },
                        "intrinsics": {
                            "type": "string",
                            "format": "binary",
                            "description": (
                                "The camera matrix K in pixels as text (a file or a text "
                                "field, at most 64 KiB): three lines of three numbers "
                                "separated by commas or spaces, upper triangular with last "
                                "row 0, 0, 1 and positive focal lengths; lines starting "
                                "with # are skipped. Replaces the K of a tracks file. Not "
                                "with 'focal'."
                            ),
                        },
                    },
                },
                "encoding": {
                    "file": {"contentType": "application/octet-stream"},
                    "mask": {"contentType": "image/png"},
                    "intrinsics": {"contentType": "text/plain"},
                },
            },
            "application/json": {
                "schema": {"$ref": "#/components/schemas/TracksBody"},
                "examples": {
                    "three_points_two_frames": {
                        "summary": "A tiny input (real inputs have thousands of points)",
                        "value": {
                            "tracks": [
                                [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
                                [[0.1, 0.0], [1.0, 0.1], [0.0, 0.9]],
                            ],
                            "params": {"max_iter": 50},
                        },
                    }
                },
            },
        },
    }
}


@router.post(
    "",
    operation_id="create_job",
    summary="Submit a reconstruction job",
    description=(
        "Upload dense 2D tracks and solver parameters. The input is validated completely "
        "(shape, dtype, missing entries, size limits; pickles are refused) before the job is "
        "queued. Points missing from some frames are accepted (NaN, a visibility mask, "
        "missing CSV rows, or [null, null] in JSON tracks): the job's `input.observed_fraction` "
        "says how much was observed, and the result holds every point in every frame. "
        "Answers 202 with the job resource and a `Location` header naming it.\n\n"
        "The optional fields `focal` (pixels) or `intrinsics` (the 3 x 3 matrix K as text) "
        "give the camera; the job's `input.camera` shows the K it solves with.\n\n"
        "curl example:\n\n"
        "    curl -F file=@face_small.npz -F 'params={\"max_iter\": 100}' "
        "http://127.0.0.1:8000/v1/jobs"
    ),
    status_code=status.HTTP_202_ACCEPTED,
    response_model=JobResource,
    responses={
        202: {
            "description": "Accepted and queued.",
            "headers": {
                "Location": {
                    "description": "Path of the new job resource, /v1/jobs/{id}.",
                    "schema": {"type": "string"},
                }
            },
        },
        408: {
            "model": ErrorBody,
            "description": "The body stopped arriving for MOJU_BODY_TIMEOUT seconds.",
        },
        413: {
            "model": ErrorBody,
            "description": (
                "The upload (or a JSON body), or the memory its job would need, exceeds a "
                "limit; checked from the file's headers before its data is read."
            ),
        },
        415: {"model": ErrorBody, "description": "Neither multipart/form-data nor JSON."},
        422: {
            "model": ErrorBody,
            "description": "The input or a parameter is unusable (the message says why).",
            "content": {
                "application/json": {
                    "example": {"detail": "unknown parameter 'max_itr'; known parameters: ..."}
                }
            },
        },
        429: {
            "model": ErrorBody,
            "description": (
                "The caller has too many jobs queued or running (MOJU_MAX_QUEUED_JOBS_PER_KEY)."
            ),
            "headers": {
                "Retry-After": {
                    "description": "Seconds to wait before submitting again.",
                    "schema": {"type": "integer"},
                }
            },
        },
        503: {"model": ErrorBody, "description": "Redis is unreachable."},
    },
    openapi_extra=_SUBMIT_BODY,
)
async def create_job(
    request: Request, services: ServicesDep, caller: Caller, response: Response
) -> JobResource:
    """Validate, store and enqueue one job."""
    submission = await read_submission(request, services.settings, services.upload_checks)
    record = JobRecord(
        id=uuid4(),
        status=JobStatus.QUEUED,
        created_at=datetime.now(timezone.utc),
        parameters=submission.params,
        input=submission.summary,
    ).owned_by(caller)
    try:
        await anyio.to_thread.run_sync(_store_and_enqueue, services, record, submission)
    finally:
        submission.close()
    logger.info(
        "job %s queued for %s: %d frames x %d points",
        record.id,
        caller or "anonymous",
        record.input.frames,
        record.input.points,
    )
    response.headers["Location"] = f"/v1/jobs/{record.id}"
    return job_resource(record)


@router.get(
    "",
    operation_id="list_jobs",
    summary="List jobs, newest first",
    description=(
        "Offset pagination: `limit` jobs starting at `offset`; the response says "
        "`pagination: offset` and gives `next_offset` (null on the last page) and `total`.\n\n"
        "    curl 'http://127.0.0.1:8000/v1/jobs?limit=20&offset=0'"
    ),
    response_model=JobList,
)
def list_jobs(
    services: ServicesDep,
    caller: Caller,
    limit: Annotated[int, Query(ge=1, le=100, description="Jobs per page.")] = 20,
    offset: Annotated[
        int, Query(ge=0, le=MAX_OFFSET, description="Jobs to skip (newest first).")
    ] = 0,
) -> JobList:
    """One page of the caller's job list."""
    records, total = services.store.page(limit, offset, caller)
    next_offset = offset + limit if offset + limit < total else None
    return JobList(
        items=[job_resource(record) for record in records],
        total=total,
        limit=limit,
        offset=offset,
        next_offset=next_offset,
    )


@router.get(
    "/{job_id}",
    operation_id="get_job",
    summary="Get a job",
    description=(
        "The job resource: status (queued, running, finished, failed, cancelled), latest "
        "progress, timestamps, parameters, input summary, and for failed jobs the error.\n\n"
        f"    curl http://127.0.0.1:8000/v1/jobs/{_EXAMPLE_ID}"
    ),
    response_model=JobResource,
    responses={404: _NOT_FOUND},
)
async def get_job(job_id: JobId, services: ServicesDep, caller: Caller) -> JobResource:
    """The job resource (the route clients poll: kept off the thread pool)."""
    return job_resource(await load_record_async(services, job_id, caller))


def _event(name: str, data: str) -> str:
    return f"event: {name}\ndata: {data}\n\n"


async def _job_events(services: Services, job_id: UUID) -> AsyncIterator[str]:
    """Server-sent events: the job resource on each change, then ``end`` with the last one."""
    yield "retry: 2000\n\n"
    previous = None
    last_sent = time.monotonic()
    while True:
        record = await services.store.get_async(job_id)
        if record is None:
            # Deleted while we watched it.
            yield _event("end", json.dumps({"id": str(job_id), "status": None, "deleted": True}))
            return
        payload = job_resource(record).model_dump_json()
        if record.status.is_terminal:
            yield _event("end", payload)
            return
        if payload != previous:
            yield _event("progress", payload)
            previous = payload
            last_sent = time.monotonic()
        elif time.monotonic() - last_sent > EVENT_KEEPALIVE_SECONDS:
            yield ": keep-alive\n\n"
            last_sent = time.monotonic()
        await anyio.sleep(EVENT_POLL_SECONDS)


@router.get(
    "/{job_id}/events",
    operation_id="stream_job_events",
    summary="Follow a job's progress (server-sent events)",
    description=(
        "A `text/event-stream`: an event `progress` carrying the job resource each time it "
        "changes (status or progress), then one event `end` carrying the job resource in its "
        "terminal status (finished, failed or cancelled), after which the server closes the "
        "stream. A comment line is sent every 15 s of silence.\n\n"
        f"    curl -N http://127.0.0.1:8000/v1/jobs/{_EXAMPLE_ID}/events"
    ),
    response_class=StreamingResponse,
    responses={
        200: {
            "description": "The event stream.",
            "content": {
                "text/event-stream": {
                    "schema": {"type": "string"},
                    "example": (
                        'event: progress\ndata: {"id": "...", "status": "running", ...}\n\n'
                        'event: end\ndata: {"id": "...", "status": "finished", ...}\n\n'
                    ),
                }
            },
        },
        404: _NOT_FOUND,
    },
)
async def stream_job_events(
    job_id: JobId, services: ServicesDep, caller: Caller
) -> StreamingResponse:
    """Stream the job's progress until it ends."""
    await load_record_async(services, job_id, caller)  # 404 now rather than an empty stream
    return StreamingResponse(
        _job_events(services, job_id),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )


@router.delete(
    "/{job_id}",
    operation_id="delete_job",
    summary="Cancel a job and delete its data",
    description=(
        "A queued job is taken out of the queue; a running job stops at its worker's next "
        "iteration. The job's files (input and result) are deleted. A job that was still "
        "queued or running stays visible with status `cancelled` until its retention period "
        "ends, so anyone following it learns how it ended; a job that had already ended "
        "disappears (404 afterwards).\n\n"
        f"    curl -X DELETE http://127.0.0.1:8000/v1/jobs/{_EXAMPLE_ID}"
    ),
    status_code=status.HTTP_204_NO_CONTENT,
    response_class=Response,
    responses={204: {"description": "Cancelled and/or deleted."}, 404: _NOT_FOUND},
)
def delete_job(job_id: JobId, services: ServicesDep, caller: Caller) -> Response:
    """Cancel (if still active) and delete."""
    record = load_record(services, job_id, caller)
    if not record.status.is_terminal and services.store.cancel(job_id):
        # The record now says cancelled, which a worker that took the job will see; a job
        # still waiting in RQ's queue is also removed from it so that no worker starts it.
        queueing.cancel_in_queue(services.redis, services.store.rq_job_of(job_id))
        logger.info("job %s cancelled (was %s)", job_id, record.status.value)
    else:
        times_queued = services.store.times_queued(job_id)
        services.store.remove(job_id, record.owner)
        queueing.forget(services.redis, job_id, times_queued)
        logger.info("job %s deleted", job_id)
    services.storage.delete(job_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


#: Models referenced only by the hand-written request body above; the app adds them to the
#: OpenAPI components.
EXTRA_SCHEMAS = (TracksBody, SolverParams)
