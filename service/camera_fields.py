"""The camera fields of ``POST /v1/jobs``: ``focal`` or ``intrinsics``, read, checked, applied.

* ``focal``: a focal length in pixels, with the principal point at the image centre
  (:meth:`moju_core.cameras.intrinsics.Intrinsics.from_focal`, as ``moju track --focal``); it
  needs the frame size: a video's, or the ``frame_size`` of a tracks file.
* ``intrinsics``: the 3 x 3 matrix K in pixels as text (a file part or a text field), three
  lines of three numbers, parsed by :func:`moju_core.cameras.intrinsics.parse_intrinsics` (as
  ``moju track --intrinsics``).

The two are mutually exclusive. Without either, a video gets the default camera of its frame
size (:meth:`~moju_core.cameras.intrinsics.Intrinsics.default_for`, as ``moju track`` and
``moju reconstruct``) and a tracks file keeps its own ``K`` (else the default camera of its
``frame_size``, else none: orthographic tracks). Given, the form's camera replaces a tracks
file's ``K``, as the command-line options do.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from starlette.datastructures import FormData, UploadFile

from moju_core.cameras.intrinsics import MAX_INTRINSICS_BYTES, Intrinsics, parse_intrinsics
from moju_core.errors import MeasurementError
from moju_core.io import Measurements
from service.errors import InvalidInput
from service.schemas import CameraSource, CameraSummary
from service.validation_messages import shorten

#: The form fields read here.
CAMERA_FIELDS = ("focal", "intrinsics")
#: Longest 'focal' text read (a number of pixels fits in a few characters).
MAX_FOCAL_CHARS = 64
_INTRINSICS_NAME = "the 'intrinsics' field"
_BOTH = (
    "the 'focal' and 'intrinsics' fields both give the camera; send one of them: "
    "'intrinsics' for the full matrix K, or 'focal' for a focal length in pixels with the "
    "principal point at the image centre"
)
_FOCAL_EXAMPLE = "a number of pixels such as 800 (curl: -F focal=800)"


@dataclass(frozen=True)
class CameraRequest:
    """The camera a submission asks for: a focal length or a matrix, as plain values (it
    travels to the upload check's child process)."""

    focal: float | None = None
    matrix: tuple[tuple[float, ...], ...] | None = None

    @property
    def source(self) -> CameraSource:
        """The field that gave the camera: ``"focal"`` or ``"intrinsics"``."""
        return "focal" if self.matrix is None else "intrinsics"

    def resolve(self, frame_size: tuple[int, int] | None, what: str) -> Intrinsics:
        """The camera for frames of ``frame_size`` (None: unknown, refused for a focal
        length); ``what`` names the input in the message."""
        if self.matrix is not None:
            return Intrinsics(np.array(self.matrix), "given")
        if self.focal is None:
            raise ValueError("a camera request holds a focal length or a matrix")
        if frame_size is None:
            raise MeasurementError(
                f"the 'focal' field needs the frame size to put the principal point at the "
                f"image centre, and {what} has no frame_size; send the full matrix K in the "
                "'intrinsics' field instead, or add frame_size = (width, height) to the file"
            )
        return Intrinsics.from_focal(self.focal, frame_size)


def summary(intrinsics: Intrinsics, source: CameraSource) -> CameraSummary:
    """The job record's view of a camera and where it came from."""
    return CameraSummary(K=intrinsics.K.tolist(), source=source)


def _given(value: Any) -> bool:
    """Whether a form value was filled in: a browser sends an empty text, or an empty file
    part without a name, for a field left blank."""
    if value is None:
        return False
    if isinstance(value, UploadFile):
        return bool(value.filename) or bool(value.size)
    return bool(value.strip())


def _focal(value: str | UploadFile) -> float:
    """The 'focal' field in pixels, judged by the library's rule for a focal length
    (:meth:`Intrinsics.from_focal`: a positive finite number; the frame size plays no part in
    that check, so any will do here)."""
    if isinstance(value, UploadFile):
        raise InvalidInput(f"the 'focal' field must be text: {_FOCAL_EXAMPLE}")
    text = value.strip()
    if len(text) > MAX_FOCAL_CHARS:
        raise InvalidInput(
            f"the 'focal' field is {len(text)} characters long; give {_FOCAL_EXAMPLE}"
        )
    try:
        focal = float(text)
    except ValueError:
        raise InvalidInput(
            f"the 'focal' field {shorten(text)!r} is not a number; give {_FOCAL_EXAMPLE}"
        ) from None
    try:
        return Intrinsics.from_focal(focal, (1, 1)).fx
    except MeasurementError as exc:
        raise InvalidInput(f"the 'focal' field: {exc}; give {_FOCAL_EXAMPLE}") from None


async def _matrix(value: str | UploadFile) -> tuple[tuple[float, ...], ...]:
    """The 'intrinsics' field (a file part or text) as K, parsed by the library."""
    if isinstance(value, UploadFile):
        raw = await value.read(MAX_INTRINSICS_BYTES + 1)
    else:
        raw = value.encode("utf-8")
    try:
        intrinsics = parse_intrinsics(raw, _INTRINSICS_NAME)
    except MeasurementError as exc:
        raise InvalidInput(str(exc)) from None
    return tuple(tuple(row) for row in intrinsics.K.tolist())


async def read_camera_fields(form: FormData) -> CameraRequest | None:
    """The camera of a multipart form, or None when neither field was filled in.

    Raises InvalidInput (422) for both fields, or for a value the library refuses.
    """
    focal, matrix = form.get("focal"), form.get("intrinsics")
    has_focal, has_matrix = _given(focal), _given(matrix)
    if has_focal and has_matrix:
        raise InvalidInput(_BOTH)
    if has_focal:
        return CameraRequest(focal=_focal(focal))
    if has_matrix:
        return CameraRequest(matrix=await _matrix(matrix))
    return None


def video_camera(request: CameraRequest | None, frame_size: tuple[int, int]) -> CameraSummary:
    """The camera of a video upload: the form's, else the default of its frame size."""
    if request is None:
        return summary(Intrinsics.default_for(frame_size), "default")
    try:
        return summary(request.resolve(frame_size, "the video"), request.source)
    except MeasurementError as exc:
        raise InvalidInput(str(exc)) from None


def apply_camera(
    request: CameraRequest | None, measurements: Measurements, what: str
) -> CameraSummary | None:
    """Give ``measurements`` the form's camera (replacing the file's K); return the camera
    they carry then, or None for tracks without one (orthographic)."""
    if request is not None:
        measurements.intrinsics = request.resolve(measurements.frame_size, what)
        return summary(measurements.intrinsics, request.source)
    intrinsics = measurements.intrinsics
    if intrinsics is None:
        return None
    return summary(intrinsics, "default" if intrinsics.origin == "default" else "file")
