"""Configuration of the API, the workers and ``moju serve``: one ``BaseSettings`` class.

Every field is read from an environment variable named ``MOJU_<FIELD>`` (for example
``MOJU_REDIS_URL``). The table in ``docs/service.md`` documents each one; keep the two in step.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from pydantic import AliasChoices, Field, SecretStr, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from moju_core.footage.video import VideoLimits

MIB = 2**20
GIB = 2**30


#: The setting that bounds a job's estimated solver memory, named in refusals.
WORKER_MEMORY_SETTING = "MOJU_WORKER_MEMORY_BYTES"


class Settings(BaseSettings):
    """Settings shared by the API process, the worker processes and ``moju serve``.

    The API and the workers must agree on ``redis_url``, ``data_dir`` and ``queue_name``:
    the API writes a job's input under ``data_dir`` and the worker that picks the job from
    the queue reads it from there.
    """

    model_config = SettingsConfigDict(env_prefix="MOJU_", extra="ignore", frozen=True)

    redis_url: str | None = Field(
        None,
        description=(
            "Redis holding the job queue and job records, e.g. redis://127.0.0.1:6379/0. "
            "Required by the API and the workers; when unset, `moju serve` starts a private "
            "Redis on loopback."
        ),
    )
    data_dir: Path = Field(
        Path("moju-data"),
        description="Directory (shared volume) holding every job's input and result files.",
    )
    queue_name: str = Field("moju", min_length=1, description="Name of the RQ queue.")
    max_upload_bytes: int = Field(
        256 * MIB, ge=1024, description="Largest request body accepted by POST /v1/jobs."
    )
    max_json_bytes: int = Field(
        4 * MIB,
        ge=1024,
        description=(
            "Largest JSON body accepted by POST /v1/jobs (413 above; larger inputs go as a "
            "file). Parsed JSON takes about 16 times its size in memory."
        ),
    )
    body_timeout: float = Field(
        30.0,
        gt=0,
        le=3600,
        description=(
            "Seconds a request body may make no progress (no byte arriving) before the "
            "request is answered 408 and its partial upload deleted."
        ),
    )
    header_timeout: float = Field(
        20.0,
        gt=0,
        le=3600,
        description=(
            "Seconds a client has to send a request's headers, from the moment it connects "
            "(or its previous answer ended); a connection that takes longer is closed."
        ),
    )
    min_body_rate: int = Field(
        500,
        ge=0,
        description=(
            "Bytes per second a request body must arrive at on average, once "
            "body_rate_grace seconds have passed since its headers; a slower upload is "
            "answered 408 and its connection closed. 0: no minimum."
        ),
    )
    body_rate_grace: float = Field(
        20.0,
        gt=0,
        le=3600,
        description="Seconds a request body may take before min_body_rate is enforced.",
    )
    idle_timeout: int = Field(
        5,
        ge=1,
        le=3600,
        description=(
            "Seconds a connection may stay open between two requests (HTTP keep-alive) "
            "before the server closes it."
        ),
    )
    upload_checks: int = Field(
        2,
        ge=1,
        le=64,
        description=(
            "Uploads checked (parsed and validated) at once, each in a child process of the "
            "API; more wait their turn, so parallel uploads queue instead of adding up."
        ),
    )
    upload_check_memory_bytes: int = Field(
        2 * GIB,
        ge=64 * MIB,
        description=(
            "Memory one upload check may take (its child process's address space, beyond "
            "what it starts with); an upload that needs more is refused with 413. The "
            "child ends after the check, so its memory goes back to the system."
        ),
    )
    upload_check_timeout: float = Field(
        300.0,
        gt=0,
        le=3600,
        description="Seconds one upload check may run before it is stopped (413).",
    )
    max_points: int = Field(50_000, ge=3, description="Largest number of points P per job.")
    max_frames: int = Field(2_000, ge=2, description="Largest number of frames F per job.")
    max_video_bytes: int = Field(
        128 * MIB,
        ge=1024,
        description=(
            "Largest video file accepted by POST /v1/jobs (the whole body is also bounded by "
            "max_upload_bytes)."
        ),
    )
    max_video_width: int = Field(1920, ge=16, description="Widest video frame, in pixels.")
    max_video_height: int = Field(1080, ge=16, description="Tallest video frame, in pixels.")
    max_video_frames: int = Field(
        600, ge=2, description="Most frames of an uploaded video (all of them are tracked)."
    )
    max_video_seconds: float = Field(
        120.0,
        gt=0,
        description="Longest uploaded video, in seconds (from the frame rate it declares).",
    )
    worker_memory_bytes: int = Field(
        8 * GIB,
        ge=256 * MIB,
        # MOJU_MAX_JOB_MEMORY_BYTES is the name this setting had before; still read.
        validation_alias=AliasChoices(
            "worker_memory_bytes", "MOJU_WORKER_MEMORY_BYTES", "MOJU_MAX_JOB_MEMORY_BYTES"
        ),
        description=(
            "Memory a worker may spend on one job: a job whose estimated solver memory "
            "(moju_core.feasibility.estimate_memory_bytes) is larger is refused at submission "
            "with 413 (and by a worker that takes it anyway)."
        ),
    )
    job_timeout: int = Field(
        3600, ge=1, description="Seconds a job may run before its worker stops it (RQ timeout)."
    )
    result_ttl: int = Field(
        7 * 24 * 3600,
        ge=1,
        description=(
            "Seconds a job record and its files are kept after the job ended (finished, "
            "failed or cancelled); RQ's result_ttl and failure_ttl."
        ),
    )
    worker_threads: int = Field(
        1,
        ge=1,
        le=256,
        description="BLAS/OpenMP threads of each worker process (threadpoolctl limit).",
    )
    worker_niceness: int = Field(
        0,
        ge=0,
        le=19,
        description=(
            "Added to each worker's nice value, so that solving yields the CPU to the API "
            "when both share a machine."
        ),
    )
    cleanup_interval: int = Field(
        600,
        ge=0,
        description=(
            "Seconds between the API's sweeps that delete files of expired jobs; 0 disables."
        ),
    )

    heartbeat_interval: float = Field(
        5.0,
        gt=0,
        le=600,
        description=(
            "Seconds between two heartbeats of a work horse running a job, and between two "
            "looks of the API's watchdog for jobs whose worker is gone."
        ),
    )
    heartbeat_ttl: float = Field(
        30.0,
        gt=0,
        le=3600,
        description=(
            "Seconds without a heartbeat after which a running job's worker counts as lost "
            "(killed, machine gone); at least twice heartbeat_interval."
        ),
    )
    lost_job_retries: int = Field(
        1,
        ge=0,
        le=10,
        description=(
            "How many times a job whose worker was lost is queued again (for another worker) "
            "before it is failed with 'worker lost'."
        ),
    )
    api_keys: SecretStr | None = Field(
        None,
        description=(
            "API keys, comma separated: each the key itself or 'sha256:<hex digest of the "
            "key>'. When any key is configured (here or in api_keys_file) every /v1 route "
            "needs one."
        ),
    )
    api_keys_file: Path | None = Field(
        None,
        description=(
            "File of API keys, one per line in the same forms as api_keys ('#' starts a comment)."
        ),
    )
    max_queued_jobs_per_key: int = Field(
        100,
        ge=0,
        description=(
            "Most jobs one API key (or, without keys, all clients together) may have queued "
            "or running at once; more are refused with 429 and Retry-After. 0: no limit."
        ),
    )
    cors_origins: str = Field(
        "",
        description=(
            "Origins allowed to call the API from a browser page served elsewhere, comma "
            "separated (e.g. https://viewer.example.org), or '*'; empty: CORS off."
        ),
    )

    @model_validator(mode="after")
    def _heartbeat_ttl_covers_missed_beats(self) -> Settings:
        if self.heartbeat_ttl < 2 * self.heartbeat_interval:
            raise ValueError(
                f"heartbeat_ttl ({self.heartbeat_ttl:g} s) must be at least twice "
                f"heartbeat_interval ({self.heartbeat_interval:g} s), so that one late "
                "heartbeat does not count as a lost worker"
            )
        return self

    @property
    def cors_origin_list(self) -> list[str]:
        """``cors_origins`` as a list (empty: CORS off)."""
        return [origin.strip() for origin in self.cors_origins.split(",") if origin.strip()]

    @property
    def video_limits(self) -> VideoLimits:
        """What an uploaded video may hold (the tracks are bounded by max_points)."""
        return VideoLimits(
            max_bytes=self.max_video_bytes,
            max_width=self.max_video_width,
            max_height=self.max_video_height,
            max_frames=min(self.max_video_frames, self.max_frames),
            max_seconds=self.max_video_seconds,
            max_points=self.max_points,
        )

    def require_redis_url(self) -> str:
        """The Redis URL, or a ``RuntimeError`` that says how to provide one."""
        if not self.redis_url:
            raise RuntimeError(
                "MOJU_REDIS_URL is not set: point it at a Redis server "
                "(e.g. redis://127.0.0.1:6379/0), or run `moju serve`, which starts one"
            )
        return self.redis_url


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """Settings read from the environment once per process."""
    return Settings()
