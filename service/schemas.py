"""Pydantic models of the HTTP API: the job resource, its parts, the job list, request bodies.

Solver parameters are :class:`moju_core.params.SolverParams` itself, never a copy, so the API,
the worker and the CLI accept exactly the same parameters.
"""

from __future__ import annotations

import math
from datetime import datetime
from typing import Literal
from uuid import UUID

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, field_validator

from moju_core.params import SolverParams
from moju_core.result import RESULT_STOP_REASONS, Stage, StopReason
from service.states import JobStatus

_EXAMPLE_ID = "0b7e9f6c-3a51-4f0e-9d7c-2c1e8a4b5d60"

#: Where a job's camera came from (:class:`CameraSummary`).
CameraSource = Literal["focal", "intrinsics", "file", "default"]


class VideoSummary(BaseModel):
    """What the API found in an uploaded video, from its headers and first frames."""

    model_config = ConfigDict(extra="forbid")

    width: int = Field(description="Frame width in pixels.", examples=[320])
    height: int = Field(description="Frame height in pixels.", examples=[240])
    fps: float | None = Field(None, description="Frame rate the container declares.")
    has_mask: bool = Field(
        description="A mask of the object was uploaded; without one the textured region of "
        "the first frame is tracked."
    )
    step: int = Field(description="Grid spacing of the tracked points, in pixels.", examples=[4])


class TrackingSummary(BaseModel):
    """Outcome of the tracking stage of a video job (the tracks are in tracks.npz)."""

    model_config = ConfigDict(extra="forbid")

    tracks: int = Field(description="Tracks started on the first frame.", examples=[4800])
    reconstructed: int = Field(
        description="Tracks seen in 2 frames or more: the points of the result.",
        examples=[4750],
    )
    fraction_kept: float = Field(
        ge=0.0, le=1.0, description="Fraction of the track-frames with a position."
    )
    seconds: float = Field(description="Time the tracking took.", examples=[3.2])


class CameraSummary(BaseModel):
    """The camera of the job's pixel tracks (docs/cameras.md) and where it came from."""

    model_config = ConfigDict(extra="forbid")

    K: list[list[float]] = Field(
        description=(
            "The 3 x 3 camera matrix in pixels, [[fx, s, cx], [0, fy, cy], [0, 0, 1]]; "
            "pixel centres at integers, so the image centre is ((width - 1) / 2, "
            "(height - 1) / 2)."
        ),
        examples=[[[115.2, 0.0, 47.5], [0.0, 115.2, 35.5], [0.0, 0.0, 1.0]]],
    )
    source: CameraSource = Field(
        description=(
            "Where K came from: the 'focal' form field (principal point at the image "
            "centre), the 'intrinsics' form field, the K of the uploaded tracks file, or the "
            "default camera of the frame size (focal length 1.2 x the larger side, principal "
            "point at the image centre)."
        ),
        examples=["focal"],
    )


class InputSummary(BaseModel):
    """What the API found in the upload, after validation."""

    model_config = ConfigDict(extra="forbid")

    frames: int = Field(description="Number of frames F.", examples=[10])
    points: int = Field(
        description=(
            "Number of tracked points P. For a video: the grid points to track (on the mask; "
            "without one, on the whole frame, an upper bound); result.tracking says how many "
            "were reconstructed."
        ),
        examples=[2000],
    )
    format: Literal["npz", "h5", "csv", "json", "video"] = Field(
        description="How the measurements were sent (video: tracked by the worker first).",
        examples=["npz"],
    )
    filename: str | None = Field(
        None,
        max_length=255,
        description="Name of the uploaded file as the client gave it (display only).",
        examples=["face_small.npz"],
    )
    size_bytes: int = Field(
        description="Size of the uploaded file (or of the JSON body) in bytes.", examples=[331_000]
    )
    has_rotations: bool = Field(description="The input carries camera rotations R.")
    has_ground_truth: bool = Field(
        description="The input carries ground-truth shapes gt (enables the metrics endpoint)."
    )
    has_faces: bool = Field(description="The input carries triangles (exported in PLY files).")
    has_colors: bool = Field(description="The input carries per-point colours.")
    observed_fraction: float = Field(
        1.0,
        gt=0.0,
        le=1.0,
        description=(
            "Fraction of the F x P (frame, point) entries that are observed: 1 when every "
            "point is tracked in every frame, less when some are missing (NaN or visibility "
            "False in the upload); the solver fills in the others."
        ),
        examples=[0.85],
    )
    video: VideoSummary | None = Field(None, description="For a video upload: what it holds.")
    camera: CameraSummary | None = Field(
        None,
        description=(
            "The camera the job solves with (K in pixels): always for a video; for tracks "
            "when the form gave one or the file has K or a frame_size. Null: tracks without "
            "a camera, solved as orthographic."
        ),
    )


class ProgressReport(BaseModel):
    """Latest progress a worker reported (throttled to about two reports a second)."""

    model_config = ConfigDict(extra="forbid")

    stage: str = Field(
        description=(
            "One of "
            + ", ".join([*Stage, "finished"])
            + " (tracking: video jobs only, the tracker's stage before the solve)."
        ),
        examples=["iterating"],
    )
    iteration: int = Field(
        description="ADMM iterations done so far (while tracking: frames tracked).", examples=[42]
    )
    max_iter: int = Field(
        description="Iteration cap (params.max_iter; while tracking: the video's frames).",
        examples=[300],
    )
    gap: float | None = Field(
        None, description="Primal gap of the last iteration; null before the loop starts."
    )
    rho: float | None = Field(None, description="Current ADMM penalty parameter.")
    fraction: float = Field(
        ge=0.0,
        le=1.0,
        description="Estimated fraction of the current stage's work done (tracking, then solve).",
        examples=[0.4],
    )
    elapsed: float = Field(
        description="Seconds since the solver (while tracking: the tracker) started.",
        examples=[1.8],
    )
    eta: float | None = Field(None, description="Estimated seconds left; null when unknown.")

    @field_validator("gap", "rho", "eta", mode="before")
    @classmethod
    def _nan_to_none(cls, value: float | None) -> float | None:
        # JSON has no NaN; the solver reports gap = nan before the first iteration.
        if isinstance(value, float) and not math.isfinite(value):
            return None
        return value


class CompletionSummary(BaseModel):
    """How the hidden entries of an input with missing points were completed before the solve
    (the low-rank model of the tracks that fills them; docs/solver.md, "Missing data")."""

    model_config = ConfigDict(extra="forbid")

    rank: int = Field(description="Rank of the low-rank model of the tracks.", examples=[6])
    exact: bool = Field(
        description=(
            "Whether the tracks are exactly of that rank: the model then predicts the hidden "
            "entries it trusts as precisely as measurements."
        ),
        examples=[False],
    )
    held_out_error: float | None = Field(
        None,
        description=(
            "For a model that is not exact: its error on held-out observed entries beyond the "
            "noise, relative to a rank-1 model's (0: everything held out was predicted; large "
            "values mean the filled-in points carry little more than the priors). Null for an "
            "exact model."
        ),
        examples=[0.023],
    )


class ResultSummary(BaseModel):
    """Outcome of a finished reconstruction (the arrays are in the result download)."""

    model_config = ConfigDict(extra="forbid")

    n_iter: int = Field(description="ADMM iterations run.", examples=[120])
    stop_reason: StopReason = Field(
        description="Why the loop stopped: " + ", ".join(RESULT_STOP_REASONS) + ".",
        json_schema_extra={"enum": list(RESULT_STOP_REASONS)},
        examples=["converged"],
    )
    shape_gap: float | None = Field(
        None,
        description=(
            "Shape gap ||S# - f(S)||_inf of the last iteration, the quantity the loop's "
            "convergence test compares with tol; null for a closed-form solve."
        ),
        examples=[8.6e-11],
    )
    exact_fit: bool = Field(
        False,
        description=(
            "Whether the loop fitted the tracks exactly (noise-free tracks): its convergence "
            "test then stops at that fit's precision, 1e-5, when tol is finer."
        ),
    )
    timings: dict[str, float] = Field(
        description="Seconds per solver stage.", examples=[{"total": 1.2}]
    )
    resolved_parameters: SolverParams = Field(
        description="Parameters actually used, with every data-derived default filled in."
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="Warnings of the solver, e.g. a fallback it took.",
        examples=[[]],
    )
    tracking: TrackingSummary | None = Field(
        None, description="For a video job: how the tracking went."
    )
    completion: CompletionSummary | None = Field(
        None, description="For an input with missing points: how the hidden entries were completed."
    )


class JobRecord(BaseModel):
    """A job as stored in Redis: everything of the job resource except its links."""

    model_config = ConfigDict(extra="forbid")

    id: UUID = Field(description="Job id (UUID4).", examples=[_EXAMPLE_ID])
    status: JobStatus = Field(description="Lifecycle state.", examples=["running"])
    created_at: datetime = Field(description="When the API accepted the job (UTC).")
    started_at: datetime | None = Field(None, description="When a worker started it (UTC).")
    ended_at: datetime | None = Field(
        None, description="When it finished, failed or was cancelled (UTC)."
    )
    parameters: SolverParams = Field(description="Solver parameters as submitted.")
    input: InputSummary = Field(description="Summary of the validated input.")
    progress: ProgressReport | None = Field(
        None, description="Latest progress; null until a worker reports."
    )
    error: str | None = Field(
        None, description="For failed jobs: what went wrong and what to do about it."
    )
    result: ResultSummary | None = Field(None, description="For finished jobs: the outcome.")
    attempts: int = Field(
        0,
        ge=0,
        description=(
            "How many times a worker started the job: 0 while it waits for the first start, "
            "2 or more when it was started again because its worker was lost."
        ),
        examples=[1],
    )

    # The owner id of the API key that submitted the job (service.auth; "" without keys). Not
    # a field: it is never shown in the job resource.
    _owner: str = PrivateAttr(default="")

    @property
    def owner(self) -> str:
        """Owner id of the submitting API key ("" when the server has no keys)."""
        return self._owner

    def owned_by(self, owner: str) -> JobRecord:
        """This record with its owner set (returns self, for chaining)."""
        self._owner = owner
        return self


class JobLinks(BaseModel):
    """Where to find the job's other resources."""

    model_config = ConfigDict(extra="forbid")

    self: str = Field(examples=[f"/v1/jobs/{_EXAMPLE_ID}"])
    events: str = Field(examples=[f"/v1/jobs/{_EXAMPLE_ID}/events"])
    result: str = Field(examples=[f"/v1/jobs/{_EXAMPLE_ID}/result?format=h5"])
    frames_zip: str = Field(examples=[f"/v1/jobs/{_EXAMPLE_ID}/frames.zip"])
    metrics: str | None = Field(
        None, description="Present when ground truth was uploaded.", examples=[None]
    )
    tracks: str | None = Field(
        None, description="For a video job: its 2D tracks (npz).", examples=[None]
    )


class JobResource(JobRecord):
    """The job resource returned by every job endpoint."""

    links: JobLinks


class JobList(BaseModel):
    """One page of jobs, newest first, with offset pagination."""

    model_config = ConfigDict(extra="forbid")

    pagination: Literal["offset"] = Field(
        "offset", description="Pagination scheme: pass `offset` and `limit` to page."
    )
    items: list[JobResource]
    total: int = Field(description="Number of jobs currently stored.", examples=[1])
    limit: int = Field(examples=[20])
    offset: int = Field(examples=[0])
    next_offset: int | None = Field(
        None, description="Offset of the next page; null on the last page.", examples=[None]
    )


class TracksBody(BaseModel):
    """JSON alternative to a file upload, for small inputs.

    ``tracks[f][j]`` is the ``[x, y]`` image position of point ``j`` in frame ``f``.
    """

    model_config = ConfigDict(extra="forbid")

    tracks: list[list[list[float | None]]] = Field(
        description=(
            "F x P x 2 nested lists: tracks[f][j] = [x, y], or [null, null] where point j is "
            "not observed in frame f."
        ),
        examples=[[[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], [[0.1, 0.0], [1.0, 0.1], [0.0, 0.9]]]],
    )
    params: SolverParams | None = Field(None, description="Solver parameters.")
    rotations: list[list[list[float]]] | None = Field(
        None, description="Optional known camera rotations R, F x 2 x 3."
    )
    ground_truth: list[list[list[float]]] | None = Field(
        None, description="Optional ground-truth shapes gt, F x P x 3 (enables metrics)."
    )
    visibility: list[list[bool]] | None = Field(
        None,
        description=(
            "Optional F x P flags, true where point j is observed in frame f; must agree with "
            "the [null, null] entries of tracks."
        ),
    )


class ErrorBody(BaseModel):
    """Every error response: one sentence a user can act on."""

    detail: str = Field(examples=["job 0b7e9f6c-3a51-4f0e-9d7c-2c1e8a4b5d60 not found"])


class Health(BaseModel):
    """Answer of the health and readiness probes."""

    status: Literal["ok"] = "ok"
    workers: int | None = Field(
        None, description="Workers registered on the queue (readiness only)."
    )


class Metrics(BaseModel):
    """Accuracy of a finished job against the ground truth uploaded with it.

    e3D is the relative 3D error of the paper's Eq. 17 after the named alignment:
    ``procrustes`` (an orthogonal transform per frame, as in published tables), ``global``
    (one transform for the sequence) and ``sign`` (no rotation, only the better depth sign),
    over every point; with missing data also over the unobserved entries alone.
    """

    model_config = ConfigDict(extra="forbid")

    e3d_procrustes: float = Field(examples=[0.041])
    e3d_global: float = Field(examples=[0.057])
    e3d_sign: float = Field(examples=[0.62])
    rotation_error_deg: float | None = Field(
        None,
        description="Mean camera rotation error in degrees; present when true rotations "
        "were uploaded.",
        examples=[1.9],
    )
    observed_fraction: float | None = Field(
        None,
        description="Fraction of the (frame, point) entries observed; present when some "
        "were missing.",
        examples=[0.7],
    )
    e3d_occluded_procrustes: float | None = Field(
        None,
        description="e3D over the unobserved entries only (per-frame Procrustes alignment "
        "fitted on all points; each frame relative to its unobserved ground-truth points); "
        "present when some entries were missing.",
        examples=[0.08],
    )
    e3d_occluded_global: float | None = Field(
        None, description="As e3d_occluded_procrustes, with one global alignment."
    )
    e3d_occluded_sign: float | None = Field(
        None, description="As e3d_occluded_procrustes, depth sign only."
    )
