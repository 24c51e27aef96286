"""Routes that hand out a finished job's outputs: result file, PLY frames, metrics."""

from __future__ import annotations

import pathlib
import zipfile
from collections.abc import Iterator
from typing import Annotated, Literal
from uuid import UUID

from fastapi import APIRouter, Depends, Path, Query
from fastapi.responses import FileResponse, Response, StreamingResponse

from moju_core.metrics import evaluate
from moju_core.ply import frame_file_name, ply_bytes
from service.deps import Caller, JobId, Services, ServicesDep, get_caller
from service.errors import FrameOutOfRange, JobNotFinished, NoGroundTruth, NotAVideoJob
from service.routes.jobs import UNAUTHORIZED, load_record
from service.schemas import ErrorBody, JobRecord, Metrics
from service.states import JobStatus
from service.storage import JobFilesMissing
from service.track_overlay import overlay_png

router = APIRouter(
    prefix="/v1/jobs",
    tags=["downloads"],
    dependencies=[Depends(get_caller)],
    responses=UNAUTHORIZED,
)

_EXAMPLE = "http://127.0.0.1:8000/v1/jobs/0b7e9f6c-3a51-4f0e-9d7c-2c1e8a4b5d60"
_ERRORS = {
    404: {"model": ErrorBody, "description": "No such job (or no such frame)."},
    409: {"model": ErrorBody, "description": "The job has not finished, so there is no result."},
}
_MEDIA_TYPES = {"h5": "application/x-hdf5", "npz": "application/octet-stream"}


def finished_record(services: Services, job_id: UUID, owner: str) -> JobRecord:
    """The caller's finished job; 404 when unknown, 409 with the reason when unfinished."""
    record = load_record(services, job_id, owner)
    if record.status is JobStatus.FINISHED:
        return record
    if record.status is JobStatus.FAILED:
        raise JobNotFinished(f"job {job_id} failed, so it has no result: {record.error}")
    if record.status is JobStatus.CANCELLED:
        raise JobNotFinished(f"job {job_id} was cancelled, so it has no result")
    where = ""
    if record.progress is not None and record.status is JobStatus.RUNNING:
        where = f", at iteration {record.progress.iteration} of {record.progress.max_iter}"
    raise JobNotFinished(
        f"job {job_id} is {record.status.value}{where}; its result is not ready yet: wait "
        f"until its status is 'finished' (GET /v1/jobs/{job_id} or /v1/jobs/{job_id}/events)"
    )


@router.get(
    "/{job_id}/result",
    operation_id="download_result",
    summary="Download the result (HDF5 or npz)",
    description=(
        "shapes (F x P x 3, every point in every frame: the unobserved ones filled in by the "
        "solver), visibility (F x P bool, true where the point was observed), rotations "
        "(F x 2 x 3), labels (P), the convergence history, the "
        "resolved parameters, timings and metadata, in the layout of "
        "`moju_core.io.write_result` (readable with `moju_core.io.read_result`).\n\n"
        f"    curl -o result.npz '{_EXAMPLE}/result?format=npz'"
    ),
    response_class=FileResponse,
    responses={
        200: {
            "description": "The result file.",
            "content": {
                "application/x-hdf5": {"schema": {"type": "string", "format": "binary"}},
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
            },
        },
        **_ERRORS,
    },
)
def download_result(
    job_id: JobId,
    services: ServicesDep,
    caller: Caller,
    format: Annotated[
        Literal["h5", "npz"], Query(description="File format: h5 (HDF5) or npz.")
    ] = "h5",
) -> FileResponse:
    """The result file in the requested format."""
    finished_record(services, job_id, caller)
    path = services.storage.result_file(job_id, format)
    return FileResponse(path, media_type=_MEDIA_TYPES[format], filename=f"moju-{job_id}.{format}")


def _frame_ply(services: Services, job_id: UUID, frame: int) -> bytes:
    faces, colors = services.storage.mesh_attributes(job_id)
    with services.storage.result_frames(job_id) as frames:
        if frame >= frames.n_frames:
            raise FrameOutOfRange(
                f"job {job_id} has {frames.n_frames} frames (0..{frames.n_frames - 1}); there "
                f"is no frame {frame}"
            )
        return ply_bytes(frames.frame(frame), faces=faces, colors=colors)


@router.get(
    "/{job_id}/frames/{frame}.ply",
    operation_id="download_frame_ply",
    summary="Download one frame as PLY",
    description=(
        "Binary PLY of frame `frame` (0-based): P vertices (x, y, z as float32, plus colours "
        "and triangles when they were uploaded).\n\n"
        f"    curl -o frame_0000.ply {_EXAMPLE}/frames/0.ply"
    ),
    response_class=Response,
    responses={
        200: {
            "description": "The PLY file.",
            "content": {"application/x-ply": {"schema": {"type": "string", "format": "binary"}}},
        },
        **_ERRORS,
    },
)
def download_frame_ply(
    job_id: JobId,
    services: ServicesDep,
    caller: Caller,
    frame: Annotated[int, Path(ge=0, description="Frame number, 0-based.", examples=[0])],
) -> Response:
    """One frame's reconstructed shape as PLY."""
    record = finished_record(services, job_id, caller)
    data = _frame_ply(services, job_id, frame)
    name = frame_file_name(frame, record.input.frames)
    return Response(
        data,
        media_type="application/x-ply",
        headers={"Content-Disposition": f'attachment; filename="{name}"'},
    )


class _ZipSink:
    """A write-only file for :class:`zipfile.ZipFile` whose bytes are taken out as they come.

    zipfile writes a stream it cannot seek with data descriptors, so the archive can be sent
    while it is being built, one frame in memory at a time.
    """

    def __init__(self) -> None:
        self._chunks: list[bytes] = []

    def write(self, data: bytes) -> int:
        self._chunks.append(bytes(data))
        return len(data)

    def flush(self) -> None:
        """Nothing to flush: bytes are kept until :meth:`take`."""

    def take(self) -> bytes:
        data = b"".join(self._chunks)
        self._chunks.clear()
        return data


def _zip_frames(services: Services, job_id: UUID) -> Iterator[bytes]:
    faces, colors = services.storage.mesh_attributes(job_id)
    sink = _ZipSink()
    with services.storage.result_frames(job_id) as frames:
        # PLY floats barely compress; level 1 keeps the server's CPU for the solver.
        with zipfile.ZipFile(sink, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
            for frame in range(frames.n_frames):
                data = ply_bytes(frames.frame(frame), faces=faces, colors=colors)
                archive.writestr(frame_file_name(frame, frames.n_frames), data)
                yield sink.take()
    yield sink.take()


@router.get(
    "/{job_id}/frames.zip",
    operation_id="download_frames_zip",
    summary="Download every frame as PLY, in a zip",
    description=(
        "A zip archive with one binary PLY per frame (`frame_0000.ply`, ...), built while it "
        "is sent (nothing is stored).\n\n"
        f"    curl -o frames.zip {_EXAMPLE}/frames.zip"
    ),
    response_class=StreamingResponse,
    responses={
        200: {
            "description": "The zip archive.",
            "content": {"application/zip": {"schema": {"type": "string", "format": "binary"}}},
        },
        **_ERRORS,
    },
)
def download_frames_zip(job_id: JobId, services: ServicesDep, caller: Caller) -> StreamingResponse:
    """All frames as PLY files in a streamed zip."""
    finished_record(services, job_id, caller)
    # Checked now so that a missing result is a 404, not a stream broken after its headers.
    if not services.storage.has_result(job_id):
        raise JobFilesMissing(job_id)
    return StreamingResponse(
        _zip_frames(services, job_id),
        media_type="application/zip",
        headers={"Content-Disposition": f'attachment; filename="moju-{job_id}-frames.zip"'},
    )


def _compute_metrics(services: Services, job_id: UUID) -> dict[str, float]:
    measurements = services.storage.read_input(job_id)
    result = services.storage.read_result(job_id)
    rotations_true = measurements.rotations
    # The observations the solver used (stored with the result), else those of the input.
    visibility = result.visibility if result.visibility is not None else measurements.visibility
    scores = evaluate(
        result.shapes,
        measurements.ground_truth,
        R_est=result.rotations if rotations_true is not None else None,
        R_true=rotations_true,
        visibility=visibility,
    )
    return {name: float(value) for name, value in scores.items()}


@router.get(
    "/{job_id}/metrics",
    operation_id="get_job_metrics",
    summary="Accuracy against the uploaded ground truth",
    description=(
        "e3D (relative 3D error, the paper's Eq. 17) after per-frame Procrustes, global and "
        "sign-only alignment, and the mean rotation error in degrees when true rotations "
        "were uploaded. When points were missing, also the fraction observed and the e3D "
        "over the unobserved entries alone. Only for jobs whose input held ground truth `gt` "
        "(404 otherwise). "
        "Computed on the first request and cached.\n\n"
        f"    curl {_EXAMPLE}/metrics"
    ),
    response_model=Metrics,
    responses=_ERRORS,
)
def get_job_metrics(job_id: JobId, services: ServicesDep, caller: Caller) -> Metrics:
    """Accuracy figures of a finished job."""
    record = load_record(services, job_id, caller)
    if not record.input.has_ground_truth:
        raise NoGroundTruth(
            f"job {job_id} was submitted without ground truth, so there is nothing to compare "
            "with: include gt (F x P x 3) in the input file to get metrics"
        )
    finished_record(services, job_id, caller)
    cached = services.storage.read_metrics(job_id)
    if cached is None:
        cached = _compute_metrics(services, job_id)
        services.storage.write_metrics(job_id, cached)
    return Metrics(**cached)


def _video_record(services: Services, job_id: UUID, owner: str) -> JobRecord:
    record = load_record(services, job_id, owner)
    if record.input.format != "video":
        raise NotAVideoJob(
            f"job {job_id} was submitted as {record.input.format} measurements, not a video, "
            "so it has no tracks or frames of its own"
        )
    return record


@router.get(
    "/{job_id}/tracks.npz",
    operation_id="download_tracks",
    summary="Download a video job's 2D tracks",
    description=(
        "The tracker's output, as written by `moju track`: W (2F x P float64, pixel "
        "positions, x right, y down, NaN where a track is lost), visibility (F x P bool), "
        "colors (P x 3 uint8, from the first frame) and frame_size (width, height). Its P "
        "tracks are the points of the result (tracks seen in one frame only are left out). "
        "Ready once the tracking stage is over, before the solve ends; 404 for a job that was "
        "not a video upload.\n\n"
        f"    curl -o tracks.npz {_EXAMPLE}/tracks.npz"
    ),
    response_class=FileResponse,
    responses={
        200: {
            "description": "The tracks file.",
            "content": {
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}}
            },
        },
        404: {"model": ErrorBody, "description": "No such job, or not a video job."},
        409: {"model": ErrorBody, "description": "The tracking stage has not ended (or failed)."},
    },
)
def download_tracks(job_id: JobId, services: ServicesDep, caller: Caller) -> FileResponse:
    """The tracks of a video job."""
    record = _video_record(services, job_id, caller)
    path = _tracks_path(services, record)
    return FileResponse(
        path, media_type="application/octet-stream", filename=f"moju-{job_id}-tracks.npz"
    )


def _tracks_path(services: Services, record: JobRecord) -> pathlib.Path:
    """The job's tracks file, or 409 saying why there is none yet."""
    job_id = record.id
    try:
        return services.storage.tracks_file(job_id)
    except JobFilesMissing:
        if record.status is JobStatus.FAILED:
            raise JobNotFinished(
                f"job {job_id} failed before its tracks were written: {record.error}"
            ) from None
        raise JobNotFinished(
            f"job {job_id} is {record.status.value} and its tracking stage has not ended; "
            f"wait until its progress stage is past 'tracking' (GET /v1/jobs/{job_id})"
        ) from None


@router.get(
    "/{job_id}/first-frame.png",
    operation_id="download_first_frame",
    summary="The first frame of a video job",
    description=(
        "The video's first frame as PNG, decoded when it was uploaded: the frame the tracks "
        "start on (their pixel coordinates are this image's). With `overlay=tracks`, the "
        "tracks are drawn on it (each one's path over the frames, in green, with a red dot "
        "where it was last seen; 409 before the tracking stage has ended). 404 for a job "
        "that was not a video upload.\n\n"
        f"    curl -o first-frame.png '{_EXAMPLE}/first-frame.png?overlay=tracks'"
    ),
    response_class=Response,
    responses={
        200: {
            "description": "The PNG image.",
            "content": {"image/png": {"schema": {"type": "string", "format": "binary"}}},
        },
        404: {"model": ErrorBody, "description": "No such job, or not a video job."},
        409: {"model": ErrorBody, "description": "Tracks asked for before they exist."},
    },
)
def download_first_frame(
    job_id: JobId,
    services: ServicesDep,
    caller: Caller,
    overlay: Annotated[
        Literal["none", "tracks"], Query(description="Draw the tracks on the frame.")
    ] = "none",
) -> Response:
    """The first frame of a video job, with or without its tracks."""
    record = _video_record(services, job_id, caller)
    frame = services.storage.first_frame_file(job_id)
    if overlay == "none":
        return FileResponse(frame, media_type="image/png")
    return Response(overlay_png(frame, _tracks_path(services, record)), media_type="image/png")
