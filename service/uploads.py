"""Reading a job submission: size limits, multipart or JSON body, parameters, validation.

Nothing is enqueued unless the whole input passed here: the body is at most
``MOJU_MAX_UPLOAD_BYTES`` (``Content-Length`` checked first, then the bytes actually
streamed, so the server never reads more than the limit), files and JSON bodies are streamed
to disk and parsed by :func:`moju_core.io.read_measurements` in a child process with its own
memory limit (:mod:`service.check_process`, :mod:`service.input_check`: no pickles, declared
sizes checked before any data is read), and the parameters are
:class:`moju_core.params.SolverParams`.
"""

from __future__ import annotations

import codecs
import functools
import json
import shutil
import tempfile
import zipfile
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import Any

import anyio
import anyio.to_thread
from pydantic import ValidationError
from starlette.datastructures import UploadFile
from starlette.formparsers import MultiPartException, MultiPartParser
from starlette.requests import Request

from moju_core import feasibility, file_types
from moju_core.errors import MeasurementError, MeasurementTooLarge
from moju_core.params import SolverParams, rotation_method
from service.camera_fields import CAMERA_FIELDS, CameraRequest, read_camera_fields
from service.check_process import run_check, run_here
from service.errors import BodyTimeout, InvalidInput, UnsupportedMediaType, UploadTooLarge
from service.input_check import (
    HOW_TO_SEND,
    TOO_DEEP,
    CheckedInput,
    InputCheck,
    InputKind,
    admit,
    check_input,
)
from service.schemas import InputSummary
from service.settings import Settings
from service.validation_messages import describe_errors, shorten
from service.video_uploads import StagedVideo, stage_video, video_extension

_FILE_FORMATS = {".npz": "npz", ".h5": "h5", ".hdf5": "h5", ".hdf": "h5", ".csv": "csv"}
_FORM_FIELDS = ("file", "params", "mask", *CAMERA_FIELDS)
#: Longest 'params' part read when it comes as a file (every parameter fits in a few hundred).
MAX_PARAMS_BYTES = 65536
_TOO_DEEP = TOO_DEEP
_HOW_TO_SEND = HOW_TO_SEND
_COPY_CHUNK = 2**20
#: Uploads of at most this many bytes whose arrays are small are checked in a thread of the
#: API (see _known_small); others in a child process with its own memory limit.
SMALL_UPLOAD_BYTES = 2**20
#: Largest total of an npz's members (uncompressed) checked in the API's own thread.
SMALL_ARRAY_BYTES = 16 * 2**20


@dataclass(frozen=True)
class Submission:
    """A validated job submission, ready to be stored and enqueued.

    Either ``staged_input`` (the checked input, written as ``input.npz`` in a private
    temporary directory), or for a video upload ``video`` (tracked by the worker); the
    caller closes the submission (:meth:`close`) once it is stored.
    """

    staged_input: Path | None
    params: SolverParams
    summary: InputSummary
    video: StagedVideo | None = None

    def close(self) -> None:
        """Remove the temporary files (whatever was not moved into the job's area)."""
        if self.staged_input is not None:
            shutil.rmtree(self.staged_input.parent, ignore_errors=True)
        if self.video is not None:
            self.video.close()


def _mebibytes(n_bytes: int) -> str:
    return f"{n_bytes / 2**20:.1f} MiB"


def _too_large(size: int | str, limit: int) -> UploadTooLarge:
    return UploadTooLarge(
        f"the request body is {size} bytes; this server accepts at most {limit} bytes "
        f"({_mebibytes(limit)}, MOJU_MAX_UPLOAD_BYTES): subsample the points or frames, or "
        "send float32 data"
    )


def check_content_length(request: Request, limit: int) -> None:
    """Refuse a body announced as larger than ``limit`` before reading any of it."""
    declared = request.headers.get("content-length")
    if declared is None:
        return
    try:
        size = int(declared)
    except ValueError:
        raise InvalidInput(f"Content-Length {declared[:20]!r} is not a number") from None
    if size > limit:
        raise _too_large(size, limit)


async def _limited_stream(
    request: Request,
    limit: int,
    too_large: Callable[[int | str, int], UploadTooLarge] = _too_large,
    timeout: float = 30.0,
) -> AsyncIterator[bytes]:
    """The body's chunks, stopping with 413 as soon as more than ``limit`` bytes arrived and
    with 408 when no byte arrived for ``timeout`` seconds (MOJU_BODY_TIMEOUT).

    The multipart parser closes (and so deletes) its spooled files when this raises.
    """
    received = 0
    chunks = request.stream().__aiter__()
    while True:
        with anyio.move_on_after(timeout) as waited:
            try:
                chunk = await chunks.__anext__()
            except StopAsyncIteration:
                return
        if waited.cancelled_caught:
            raise BodyTimeout(
                f"no part of the request body arrived for {timeout:g} s (MOJU_BODY_TIMEOUT) "
                f"after {received} bytes; the upload was dropped. Send the whole body without "
                "pausing"
            )
        received += len(chunk)
        if received > limit:
            raise too_large(f"more than {limit}", limit)
        yield chunk


def parse_params(value: Any) -> SolverParams:
    """Validate solver parameters given as a dict (or None for all defaults)."""
    if value is None:
        return SolverParams()
    if not isinstance(value, dict):
        raise InvalidInput(
            f'params must be a JSON object such as {{"max_iter": 100}}, got {type(value).__name__}'
        )
    try:
        # Strict: "5" and true are not numbers (a client that sends them has a bug to fix).
        return SolverParams.model_validate(value, strict=True)
    except ValidationError as exc:
        raise InvalidInput(describe_errors(exc.errors(), parameters_at=None)) from None


def _params_from_form(text: str | None) -> SolverParams:
    if text is None or not text.strip():
        return SolverParams()
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidInput(
            f"the 'params' field is not valid JSON ({exc.msg} at character {exc.pos}); send a "
            'JSON object such as {"max_iter": 100}'
        ) from None
    except RecursionError:
        raise InvalidInput(_TOO_DEEP.format(what="the 'params' field")) from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits
        raise InvalidInput(f"the 'params' field cannot be read: {exc}") from None
    return parse_params(value)


def _display_name(filename: str | None) -> str | None:
    # Shown back to the user only; never used to build a path.
    if not filename:
        return None
    return PurePath(filename.replace("\\", "/")).name[:255] or None


#: Images sent where tracks or a video belong, by their first bytes.
_IMAGES = {file_types.PNG_MAGIC: "a PNG image", file_types.JPEG_MAGIC: "a JPEG image"}
#: Names of videos whose content is not a video this server reads (or is empty).
_VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".webm", ".mkv", ".avi")
_WHAT_TO_SEND = (
    "upload tracks (npz or HDF5 with W or tracks, or CSV with the header frame,point,x,y) or "
    "a video (mp4, webm or avi) in 'file'"
)


def _not_utf8_at(head: bytes) -> int | None:
    """Offset of the first byte of ``head`` that cannot start UTF-8 text (a character cut at
    the end of ``head`` is fine), or None."""
    decoder = codecs.getincrementaldecoder("utf-8")()
    try:
        decoder.decode(head, final=False)
    except UnicodeDecodeError as exc:
        return exc.start
    return None


def _file_format(upload: UploadFile) -> str:
    """npz, h5 or csv: by the first bytes (as moju_core.io does), then by the file name.

    Images, files named like a video that are none, and binary files that would otherwise be
    read as CSV are refused here (422), with what to send instead.
    """
    upload.file.seek(0)
    head = upload.file.read(file_types.HEAD_BYTES)
    upload.file.seek(0)
    found = file_types.array_file_type(head)
    if found in ("npz", "h5"):
        return found
    for magic, what in _IMAGES.items():
        if head.startswith(magic):
            raise InvalidInput(
                f"the uploaded file is {what}; {_WHAT_TO_SEND}. An image is accepted only as "
                "the 'mask' (PNG) of a video upload"
            )
    name = _display_name(upload.filename) or "the uploaded file"
    suffix = PurePath(name).suffix.lower()
    if suffix in _VIDEO_SUFFIXES:
        state = "is empty" if not head else "does not start like an mp4, webm or avi video"
        raise InvalidInput(
            f"{shorten(name)} is named like a video but {state}; {_WHAT_TO_SEND}. Check that "
            "the file is complete (videos are recognised by their first bytes)"
        )
    file_format = _FILE_FORMATS.get(suffix, "csv")
    bad_byte = _not_utf8_at(head) if file_format == "csv" else None
    if bad_byte is not None:
        raise InvalidInput(
            f"the uploaded file is not CSV text (byte {bad_byte} is not valid UTF-8), and its "
            f"first bytes are not those of an npz, HDF5 or video file; {_WHAT_TO_SEND}"
        )
    return file_format


def _staging_directory() -> Path:
    """A private temporary directory for one upload (removed by Submission.close)."""
    return Path(tempfile.mkdtemp(prefix="moju-upload-"))


def _copy_upload(upload: UploadFile, target: Path) -> None:
    """Copy the spooled upload to ``target`` in bounded chunks (blocking: worker thread)."""
    upload.file.seek(0)
    with open(target, "wb") as handle:
        shutil.copyfileobj(upload.file, handle, _COPY_CHUNK)


async def _check(
    source: Path,
    kind: InputKind,
    settings: Settings,
    limiter: anyio.CapacityLimiter,
    camera: CameraRequest | None = None,
) -> tuple[CheckedInput, Path]:
    """Check ``source`` in a child process, at most ``limiter`` at once, giving it the form's
    ``camera``; return what it found and the normalised input it wrote next to ``source``."""
    check = InputCheck(
        source=source,
        kind=kind,
        target=source.with_name("input.npz"),
        max_points=settings.max_points,
        max_frames=settings.max_frames,
        worker_memory_bytes=settings.worker_memory_bytes,
        camera=camera,
    )
    if _known_small(source, kind):
        # Its arrays are small whatever it holds: a child process would only add its start.
        checked = await anyio.to_thread.run_sync(run_here, check_input, check)
        return checked, check.target
    checked = await anyio.to_thread.run_sync(
        functools.partial(
            run_check,
            check_input,
            check,
            memory_bytes=settings.upload_check_memory_bytes,
            timeout=settings.upload_check_timeout,
        ),
        limiter=limiter,
    )
    return checked, check.target


def _known_small(source: Path, kind: InputKind) -> bool:
    """True when reading ``source`` cannot take much memory: a JSON body of at most
    :data:`SMALL_UPLOAD_BYTES` (about 16 times that once parsed; every entry is on the wire),
    or an npz of at most that size whose zip directory declares at most
    :data:`SMALL_ARRAY_BYTES` of members (the reader refuses members that hold more than
    their directory entry says). HDF5 and CSV always go to a child process: a few bytes of
    either can declare a large array (fill values; two rows naming frame 1999 and point
    49999)."""
    if source.stat().st_size > SMALL_UPLOAD_BYTES:
        return False
    if kind == "json":
        return True
    if kind != "npz":
        return False
    try:
        with zipfile.ZipFile(source) as archive:
            members = archive.infolist()
    except (zipfile.BadZipFile, OSError, ValueError):
        return False  # the check in a child process says what is wrong
    return sum(member.file_size for member in members) <= SMALL_ARRAY_BYTES


async def _checked_file(
    upload: UploadFile,
    settings: Settings,
    limiter: anyio.CapacityLimiter,
    camera: CameraRequest | None,
) -> tuple[CheckedInput, Path, str]:
    """Stage the uploaded file and check it (with the form's camera): what was found, the
    normalised input, the format."""
    file_format = _file_format(upload)
    directory = _staging_directory()
    try:
        source = directory / "upload"
        await anyio.to_thread.run_sync(_copy_upload, upload, source)
        checked, staged = await _check(source, file_format, settings, limiter, camera)  # type: ignore[arg-type]
        source.unlink()
    except BaseException:
        shutil.rmtree(directory, ignore_errors=True)
        raise
    return checked, staged, file_format


async def _from_multipart(
    request: Request, settings: Settings, limiter: anyio.CapacityLimiter
) -> Submission:
    parser = MultiPartParser(
        request.headers,
        _limited_stream(request, settings.max_upload_bytes, timeout=settings.body_timeout),
        # 'file', 'mask', 'intrinsics', plus 'params' sent as a file part (-F params=@p.json).
        max_files=4,
        # 'params', 'focal', 'intrinsics' as text, plus room for a 'file' sent as text so
        # that it gets a clear message.
        max_fields=4,
    )
    try:
        form = await parser.parse()
    except MultiPartException as exc:
        raise InvalidInput(
            f"could not read the multipart body: {exc.message.rstrip('.')}; {_HOW_TO_SEND}"
        ) from None
    try:
        unexpected = [name for name in form.keys() if name not in _FORM_FIELDS]
        if unexpected:
            raise InvalidInput(
                f"unexpected form field(s) {', '.join(repr(shorten(n)) for n in unexpected[:5])}; "
                f"{_HOW_TO_SEND}"
            )
        upload = form.get("file")
        if upload is None:
            raise InvalidInput(f"the form has no 'file' field; {_HOW_TO_SEND}")
        if not isinstance(upload, UploadFile):
            raise InvalidInput(
                "the 'file' field must be a file upload, not text (curl: -F file=@tracks.npz)"
            )
        params_field = form.get("params")
        if isinstance(params_field, UploadFile):
            text = await params_field.read(MAX_PARAMS_BYTES + 1)
            if len(text) > MAX_PARAMS_BYTES:
                raise InvalidInput(
                    f"the 'params' field is longer than {MAX_PARAMS_BYTES} bytes; send the "
                    'parameters as a flat JSON object such as {"max_iter": 100}'
                )
            params_field = text.decode("utf-8", errors="replace")
        params = _params_from_form(params_field)
        camera = await read_camera_fields(form)
        filename = _display_name(upload.filename)
        extension = video_extension(upload)
        mask = form.get("mask")
        if extension is not None:
            return await _video_submission(
                upload, mask, extension, filename, params, settings, camera
            )
        if mask is not None:
            raise InvalidInput(
                "a 'mask' goes with a video upload only (mp4, webm or avi in 'file'); the "
                "'file' is not a video"
            )
        checked, staged, file_format = await _checked_file(upload, settings, limiter, camera)
        size = upload.size or 0
    finally:
        await form.close()
    return _submission(checked, staged, params, file_format, filename, size)


async def _video_submission(
    upload: UploadFile,
    mask: Any,
    extension: str,
    filename: str | None,
    params: SolverParams,
    settings: Settings,
    camera: CameraRequest | None,
) -> Submission:
    """The submission of a video: staged and checked, with its camera (the form's, else the
    default of its frame size)."""
    if mask is not None and not isinstance(mask, UploadFile):
        raise InvalidInput("the 'mask' field must be a PNG file upload (curl: -F mask=@mask.png)")
    if params.rotations == "known":
        raise InvalidInput(
            "params.rotations is 'known' but a video has no camera rotations; choose "
            "rotations 'auto' (or leave it unset) to estimate them"
        )
    params = params.model_copy(update={"rotations": rotation_method(params.rotations, False)})
    staged = await anyio.to_thread.run_sync(
        stage_video, upload, mask, extension, filename, settings, camera
    )
    try:
        check_params_fit(params, staged.summary.frames, staged.summary.points, has_rotations=False)
    except BaseException:
        staged.close()
        raise
    return Submission(staged_input=None, params=params, summary=staged.summary, video=staged)


def _json_too_large(size: int | str, limit: int) -> UploadTooLarge:
    return UploadTooLarge(
        f"the JSON body is {size} bytes; this server reads JSON bodies of at most {limit} "
        f"bytes ({_mebibytes(limit)}, MOJU_MAX_JSON_BYTES): send larger inputs as a file, "
        "e.g. an npz upload (multipart/form-data: curl -F file=@tracks.npz)"
    )


async def _from_json(
    request: Request, settings: Settings, limiter: anyio.CapacityLimiter
) -> Submission:
    limit, too_large = settings.max_json_bytes, _json_too_large
    if settings.max_upload_bytes <= limit:
        limit, too_large = settings.max_upload_bytes, _too_large
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > limit:
        raise too_large(int(declared), limit)
    directory = _staging_directory()
    try:
        source = directory / "body.json"
        size = 0
        # Written to disk as it arrives and parsed by the check's child process: parsing
        # JSON holds the GIL and takes about 16 times the body's size in memory.
        with open(source, "wb") as body:
            async for chunk in _limited_stream(request, limit, too_large, settings.body_timeout):
                body.write(chunk)
                size += len(chunk)
        checked, staged = await _check(source, "json", settings, limiter)
        source.unlink()
        params = checked.params or SolverParams()
        return _submission(checked, staged, params, "json", None, size)
    except BaseException:
        shutil.rmtree(directory, ignore_errors=True)
        raise


def _submission(
    checked: CheckedInput,
    staged: Path,
    params: SolverParams,
    file_format: str,
    filename: str | None,
    size: int,
) -> Submission:
    """The submission of a checked input, once the parameters fit it (else 422; the staged
    files are then removed)."""
    try:
        return _fitted_submission(checked, staged, params, file_format, filename, size)
    except BaseException:
        shutil.rmtree(staged.parent, ignore_errors=True)
        raise


def _fitted_submission(
    checked: CheckedInput,
    staged: Path,
    params: SolverParams,
    file_format: str,
    filename: str | None,
    size: int,
) -> Submission:
    if params.rotations == "known" and not checked.has_rotations:
        raise InvalidInput(
            "params.rotations is 'known' but the input has no rotations: add R (F x 2 x 3) "
            "to the file (or 'rotations' to the JSON body), or choose rotations 'auto' to "
            "estimate them"
        )
    # The job record shows the resolved method ("known" or the estimator), not "unset".
    params = params.model_copy(
        update={"rotations": rotation_method(params.rotations, checked.has_rotations)}
    )
    check_params_fit(
        params, checked.n_frames, checked.n_points, has_rotations=checked.has_rotations
    )
    summary = InputSummary(
        frames=checked.n_frames,
        points=checked.n_points,
        format=file_format,
        filename=filename,
        size_bytes=size,
        has_rotations=checked.has_rotations,
        has_ground_truth=checked.has_ground_truth,
        has_faces=checked.has_faces,
        has_colors=checked.has_colors,
        observed_fraction=checked.observed_fraction,
        camera=checked.camera,
    )
    return Submission(staged_input=staged, params=params, summary=summary)


def check_params_fit(
    params: SolverParams, n_frames: int, n_points: int, *, has_rotations: bool
) -> None:
    """Refuse parameters that cannot work on F frames and P points (HTTP 422).

    The solver makes the same checks (:func:`moju_core.feasibility.check_fit`) when it runs,
    but a job refused at submission costs nobody a queue slot, and the user hears at once.
    Only sizes are compared here; the data itself is judged by the solver.
    """
    try:
        feasibility.check_fit(params, n_frames, n_points, has_rotations=has_rotations)
    except MeasurementError as exc:
        raise InvalidInput(str(exc)) from None


def check_memory(summary: InputSummary, limit: int) -> None:
    """Refuse a job whose estimated solver memory exceeds ``limit`` (HTTP 413)."""
    try:
        admit(summary.frames, summary.points, limit=limit)
    except MeasurementTooLarge as exc:
        raise UploadTooLarge(str(exc)) from None


async def read_submission(
    request: Request, settings: Settings, limiter: anyio.CapacityLimiter | None = None
) -> Submission:
    """Read, bound and validate the body of ``POST /v1/jobs``.

    Files and JSON bodies are streamed to a private temporary directory and checked in a
    child process (:mod:`service.check_process`), at most ``limiter`` at once (by default
    one at a time); the API process never holds their arrays.

    Raises
    ------
    UploadTooLarge
        Body above ``MOJU_MAX_UPLOAD_BYTES`` or estimated memory above
        ``MOJU_WORKER_MEMORY_BYTES`` (413).
    InvalidInput
        Anything wrong with the file, the tracks or the parameters (422).
    UnsupportedMediaType
        A body that is neither multipart/form-data nor JSON (415).
    """
    check_content_length(request, settings.max_upload_bytes)
    if limiter is None:
        limiter = anyio.CapacityLimiter(1)
    media_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
    try:
        if media_type == "multipart/form-data":
            submission = await _from_multipart(request, settings, limiter)
        elif media_type == "application/json":
            submission = await _from_json(request, settings, limiter)
        else:
            raise UnsupportedMediaType(
                f"unsupported content type {media_type or 'none'!r}; {_HOW_TO_SEND}"
            )
    except MeasurementTooLarge as exc:
        raise UploadTooLarge(str(exc)) from None
    except MeasurementError as exc:
        raise InvalidInput(str(exc)) from None
    try:
        check_memory(submission.summary, settings.worker_memory_bytes)
    except BaseException:
        submission.close()
        raise
    return submission
