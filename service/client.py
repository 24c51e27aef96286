"""Python client of the MoJu service (used by ``moju submit`` and the load benchmark).

Example::

    from service.client import MojuClient

    with MojuClient("http://127.0.0.1:8000") as client:
        job = client.submit("examples/face_small.npz", params={"max_iter": 100})
        job = client.wait(job.id)              # raises JobFailed / JobCancelled
        client.download(job.id, "result.npz")  # format from the extension

Every error is a :class:`MojuError`; HTTP errors carry the server's ``detail`` message.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, BinaryIO
from uuid import UUID

import httpx
from pydantic import ValidationError

from moju_core.params import SolverParams
from service.schemas import JobList, JobResource, Metrics
from service.states import JobStatus

DEFAULT_SERVER = "http://127.0.0.1:8000"

ParamsLike = SolverParams | Mapping[str, Any] | None
JobRef = UUID | str | JobResource


# ------------------------------------------------------------------------------ errors


class MojuError(Exception):
    """Base class of every error raised by :class:`MojuClient`."""


class ConnectionFailed(MojuError):
    """The server could not be reached (or stopped answering)."""


class ApiError(MojuError):
    """The server answered with an error status; ``detail`` is its message.

    ``retry_after`` is the server's Retry-After in seconds (429: too many queued jobs), or
    None.
    """

    def __init__(self, status_code: int, detail: str, retry_after: float | None = None) -> None:
        super().__init__(f"HTTP {status_code}: {detail}")
        self.status_code = status_code
        self.detail = detail
        self.retry_after = retry_after


class JobEnded(MojuError):
    """A job ended without a result; ``job`` is its final resource."""

    def __init__(self, job: JobResource, message: str) -> None:
        super().__init__(message)
        self.job = job


class JobFailed(JobEnded):
    """The job failed; the message is the server's reason."""


class JobCancelled(JobEnded):
    """The job was cancelled."""


def _raise_for_status(response: httpx.Response) -> httpx.Response:
    """Turn an error response into :class:`ApiError` with the server's message."""
    if response.is_success:
        return response
    try:
        detail = response.json().get("detail", response.text)
    except (ValueError, AttributeError):
        detail = response.text or response.reason_phrase
    if not isinstance(detail, str):
        detail = json.dumps(detail)
    try:
        retry_after = float(response.headers["retry-after"])
    except (KeyError, ValueError):
        retry_after = None
    raise ApiError(response.status_code, detail, retry_after)


def _job_id(job: JobRef) -> str:
    return str(job.id if isinstance(job, JobResource) else job)


def _params_json(params: ParamsLike) -> str | None:
    if params is None:
        return None
    if isinstance(params, SolverParams):
        return params.model_dump_json(exclude_unset=True)
    return json.dumps(dict(params))


def _form_fields(params: ParamsLike, focal: float | None) -> dict[str, str]:
    """The text fields of an upload: 'params' and 'focal' when given."""
    data = {}
    params_text = _params_json(params)
    if params_text is not None:
        data["params"] = params_text
    if focal is not None:
        data["focal"] = repr(float(focal))
    return data


def _ended(job: JobResource) -> JobResource:
    """Return a finished job; raise for a failed or cancelled one."""
    if job.status is JobStatus.FAILED:
        raise JobFailed(job, f"job {job.id} failed: {job.error}")
    if job.status is JobStatus.CANCELLED:
        raise JobCancelled(job, f"job {job.id} was cancelled")
    return job


# ------------------------------------------------------------------------------ client


class MojuClient:
    """Synchronous client of one MoJu server.

    Parameters
    ----------
    base_url : str
        Server root, e.g. ``http://127.0.0.1:8000``.
    timeout : float
        Seconds allowed for connecting and for each read (uploads and downloads included).
    transport : httpx.BaseTransport, optional
        For tests (e.g. an ASGI transport).
    api_key : str, optional
        The API key for a server that needs one, sent as ``Authorization: Bearer``.
    """

    def __init__(
        self,
        base_url: str = DEFAULT_SERVER,
        *,
        timeout: float = 60.0,
        transport: httpx.BaseTransport | None = None,
        api_key: str | None = None,
    ) -> None:
        headers = {"Authorization": f"Bearer {api_key}"} if api_key else None
        self._http = httpx.Client(
            base_url=base_url.rstrip("/"), timeout=timeout, transport=transport, headers=headers
        )

    def close(self) -> None:
        """Close the connections."""
        self._http.close()

    def __enter__(self) -> MojuClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _request(self, method: str, url: str, **kwargs: Any) -> httpx.Response:
        try:
            response = self._http.request(method, url, **kwargs)
        except httpx.TransportError as exc:
            raise ConnectionFailed(
                f"could not reach the MoJu server at {self._http.base_url} "
                f"({type(exc).__name__}: {exc}); is `moju serve` running?"
            ) from exc
        return _raise_for_status(response)

    # ---------------------------------------------------------------- jobs

    def submit(
        self,
        source: str | Path | BinaryIO,
        params: ParamsLike = None,
        *,
        filename: str | None = None,
        mask: str | Path | None = None,
        focal: float | None = None,
        intrinsics: str | Path | None = None,
    ) -> JobResource:
        """Upload a measurement file (npz, HDF5 or CSV) or a video, and queue a job.

        Parameters
        ----------
        source : path or binary file
            The measurement file, or a video (mp4, webm, avi) that the job tracks first.
        params : SolverParams or mapping, optional
            Solver parameters (unknown names are refused by the server with 422).
        filename : str, optional
            Name sent with the upload (default: the file's name); the server uses its
            extension as a format hint only.
        mask : path, optional
            With a video: PNG of the first frame's size marking the object to track.
        focal : float, optional
            The camera's focal length in pixels, with the principal point at the image
            centre (sent as the 'focal' field). Not with ``intrinsics``.
        intrinsics : path, optional
            Text file holding the camera matrix K in pixels, three lines of three numbers
            (sent as the 'intrinsics' part). Without either, a video gets the default camera
            of its frame size and a tracks file its own K (the server replaces it with the
            one given here).
        """
        data = _form_fields(params, focal)
        with contextlib.ExitStack() as stack:
            if isinstance(source, (str, Path)):
                path = Path(source)
                handle = stack.enter_context(open(path, "rb"))
                files = {"file": (filename or path.name, handle, "application/octet-stream")}
            else:
                files = {"file": (filename or "upload", source, "application/octet-stream")}
            if mask is not None:
                mask_path = Path(mask)
                files["mask"] = (mask_path.name, stack.enter_context(open(mask_path, "rb")),
                                 "image/png")  # fmt: skip
            if intrinsics is not None:
                k_path = Path(intrinsics)
                files["intrinsics"] = (k_path.name, stack.enter_context(open(k_path, "rb")),
                                       "text/plain")  # fmt: skip
            response = self._request("POST", "/v1/jobs", files=files, data=data)
        return JobResource.model_validate_json(response.content)

    def submit_tracks(self, tracks: Any, params: ParamsLike = None) -> JobResource:
        """Queue a job from tracks given as an F x P x 2 array or nested lists (small inputs)."""
        body: dict[str, Any] = {"tracks": tracks.tolist() if hasattr(tracks, "tolist") else tracks}
        params_text = _params_json(params)
        if params_text is not None:
            body["params"] = json.loads(params_text)
        response = self._request("POST", "/v1/jobs", json=body)
        return JobResource.model_validate_json(response.content)

    def get(self, job: JobRef) -> JobResource:
        """The job resource."""
        response = self._request("GET", f"/v1/jobs/{_job_id(job)}")
        return JobResource.model_validate_json(response.content)

    def list_jobs(self, *, limit: int = 20, offset: int = 0) -> JobList:
        """One page of jobs, newest first."""
        response = self._request("GET", "/v1/jobs", params={"limit": limit, "offset": offset})
        return JobList.model_validate_json(response.content)

    def cancel(self, job: JobRef) -> None:
        """Cancel the job if it is queued or running, and delete its data."""
        self._request("DELETE", f"/v1/jobs/{_job_id(job)}")

    # ---------------------------------------------------------------- following a job

    def events(self, job: JobRef) -> Iterator[tuple[str, JobResource | None]]:
        """Server-sent events of a job: ``(name, job)`` pairs until the ``end`` event.

        ``job`` is None only for the ``end`` event of a job deleted while being followed.
        """
        url = f"/v1/jobs/{_job_id(job)}/events"
        try:
            # No read timeout: a quiet stage can last longer than any sensible limit, and
            # the server sends a keep-alive comment every 15 s anyway.
            timeout = httpx.Timeout(self._http.timeout.connect, read=None)
            with self._http.stream("GET", url, timeout=timeout) as response:
                if not response.is_success:
                    response.read()
                    _raise_for_status(response)
                yield from _parse_events(response.iter_lines())
        except httpx.TransportError as exc:
            raise ConnectionFailed(f"the event stream of job {_job_id(job)} broke: {exc}") from exc

    def wait(
        self,
        job: JobRef,
        *,
        on_progress: Callable[[JobResource], None] | None = None,
        timeout: float | None = None,
        poll_interval: float | None = None,
    ) -> JobResource:
        """Block until the job ends; return it when finished, raise when not.

        Follows the server-sent events, or polls every ``poll_interval`` seconds when given
        (or when the event stream breaks).

        Raises
        ------
        JobFailed, JobCancelled
            The job ended without a result.
        TimeoutError
            ``timeout`` seconds passed first.
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        if poll_interval is None:
            try:
                for name, current in self.events(job):
                    if current is None:
                        raise JobCancelled(self.get(job), f"job {_job_id(job)} was deleted")
                    if on_progress is not None:
                        on_progress(current)
                    if name == "end":
                        return _ended(current)
                    if deadline is not None and time.monotonic() > deadline:
                        raise TimeoutError(f"job {_job_id(job)} still running after {timeout} s")
            except ConnectionFailed:
                pass  # fall back to polling below
            poll_interval = 0.5
        while True:
            current = self.get(job)
            if on_progress is not None:
                on_progress(current)
            if current.status.is_terminal:
                return _ended(current)
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"job {_job_id(job)} still running after {timeout} s")
            time.sleep(poll_interval)

    # ---------------------------------------------------------------- downloads

    def download(self, job: JobRef, path: str | Path, *, file_format: str | None = None) -> Path:
        """Save the result to ``path``; the format is ``.npz`` or ``.h5`` from its extension."""
        path = Path(path)
        file_format = file_format or {".npz": "npz", ".h5": "h5", ".hdf5": "h5"}.get(
            path.suffix.lower()
        )
        if file_format is None:
            raise ValueError(f"cannot tell the format of {path.name}: use .npz, .h5 or .hdf5")
        self._stream_to(f"/v1/jobs/{_job_id(job)}/result", path, {"format": file_format})
        return path

    def download_frames_zip(self, job: JobRef, path: str | Path) -> Path:
        """Save every frame as PLY, zipped, to ``path``."""
        path = Path(path)
        self._stream_to(f"/v1/jobs/{_job_id(job)}/frames.zip", path, None)
        return path

    def download_tracks(self, job: JobRef, path: str | Path) -> Path:
        """Save a video job's 2D tracks (npz, the layout of ``moju track``) to ``path``."""
        path = Path(path)
        self._stream_to(f"/v1/jobs/{_job_id(job)}/tracks.npz", path, None)
        return path

    def frame_ply(self, job: JobRef, frame: int) -> bytes:
        """One frame's reconstructed shape as PLY bytes."""
        return self._request("GET", f"/v1/jobs/{_job_id(job)}/frames/{int(frame)}.ply").content

    def metrics(self, job: JobRef) -> Metrics:
        """Accuracy against the ground truth uploaded with the job."""
        response = self._request("GET", f"/v1/jobs/{_job_id(job)}/metrics")
        return Metrics.model_validate_json(response.content)

    def _stream_to(self, url: str, path: Path, params: dict[str, str] | None) -> None:
        # Written under a temporary name so that an interrupted download leaves no
        # truncated file that looks complete.
        partial = path.with_name(path.name + ".part")
        try:
            with self._http.stream("GET", url, params=params) as response:
                if not response.is_success:
                    response.read()
                    _raise_for_status(response)
                with open(partial, "wb") as handle:
                    for chunk in response.iter_bytes():
                        handle.write(chunk)
            partial.replace(path)
        except httpx.TransportError as exc:
            raise ConnectionFailed(f"download from {url} broke: {exc}") from exc
        finally:
            partial.unlink(missing_ok=True)


def _parse_events(lines: Iterator[str]) -> Iterator[tuple[str, JobResource | None]]:
    """Minimal ``text/event-stream`` parser for the events this server sends."""
    name, data = "message", []
    for line in lines:
        if line == "":
            if data:
                payload = json.loads("\n".join(data))
                try:
                    job = JobResource.model_validate(payload)
                except ValidationError:
                    job = None  # the end event of a deleted job carries no resource
                yield name, job
                if name == "end":
                    return
            name, data = "message", []
        elif line.startswith(":"):
            continue
        else:
            field, _, value = line.partition(":")
            value = value.removeprefix(" ")
            if field == "event":
                name = value
            elif field == "data":
                data.append(value)
