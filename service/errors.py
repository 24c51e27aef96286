"""Domain errors of the service and the HTTP status each one maps to (in one place).

Every message is a sentence a user can act on; job errors name the job id.
"""

from __future__ import annotations

from uuid import UUID


class ServiceError(Exception):
    """Base of the errors the API turns into ``{"detail": message}`` responses."""

    status_code = 500
    #: Extra response headers (e.g. Retry-After).
    headers: dict[str, str] = {}


class JobNotFound(ServiceError):
    """No job with this id (never existed, deleted, or past its retention)."""

    status_code = 404

    def __init__(self, job_id: UUID | str) -> None:
        super().__init__(
            f"job {job_id} not found: it never existed, was deleted, or its retention period ended"
        )


class InvalidJobId(ServiceError):
    """A path parameter that is not a job id at all."""

    status_code = 404

    def __init__(self, text: str) -> None:
        shown = text if len(text) <= 64 else text[:64] + "..."
        super().__init__(
            f"job {shown!r} not found: job ids are UUID4 strings such as "
            "'0b7e9f6c-3a51-4f0e-9d7c-2c1e8a4b5d60'"
        )


class JobNotFinished(ServiceError):
    """A download was asked of a job that has no result (yet, or ever)."""

    status_code = 409


class NoGroundTruth(ServiceError):
    """Metrics were asked of a job uploaded without ground truth."""

    status_code = 404


class NotAVideoJob(ServiceError):
    """Tracks or the first frame were asked of a job that was not a video upload."""

    status_code = 404


class FrameOutOfRange(ServiceError):
    """A frame number outside 0..F-1."""

    status_code = 404


class InvalidInput(ServiceError):
    """The upload or its parameters cannot be used (HTTP 422)."""

    status_code = 422


class UnsupportedMediaType(ServiceError):
    """The request body is neither multipart/form-data nor JSON."""

    status_code = 415


class UploadTooLarge(ServiceError):
    """The upload exceeds a size limit of this server (HTTP 413)."""

    status_code = 413


class BodyTimeout(ServiceError):
    """The client stopped sending its request body (HTTP 408); the connection is closed."""

    status_code = 408

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.headers = {"Connection": "close"}


class TooManyJobs(ServiceError):
    """The caller already has as many queued or running jobs as allowed (HTTP 429)."""

    status_code = 429

    def __init__(self, message: str, *, retry_after: int) -> None:
        super().__init__(message)
        self.headers = {"Retry-After": str(retry_after)}


class NotReady(ServiceError):
    """The service cannot take jobs right now (HTTP 503)."""

    status_code = 503
