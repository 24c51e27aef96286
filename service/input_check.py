"""Reading, validating and storing one uploaded input: what the check's child process runs.

:func:`check_input` reads an upload that the API has streamed to disk (an npz, HDF5 or CSV
file, or a JSON body), validates it with :func:`moju_core.io.read_measurements` (sizes from
the headers first, then the data) and writes the normalised ``input.npz`` next to it. It runs
in a child process (:mod:`service.check_process`), so the memory it takes is bounded there
and given back to the system when the child exits; only the small :class:`CheckedInput`
travels back to the API.
"""

from __future__ import annotations

import functools
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import ValidationError

from moju_core import feasibility
from moju_core.errors import MeasurementError, MeasurementTooLarge
from moju_core.io import Measurements, read_measurements, write_measurements
from moju_core.params import SolverParams
from moju_core.validation import tracks_to_W
from service.camera_fields import CameraRequest, apply_camera
from service.errors import InvalidInput
from service.schemas import CameraSummary, TracksBody
from service.settings import WORKER_MEMORY_SETTING
from service.validation_messages import describe_errors

InputKind = Literal["npz", "h5", "csv", "json"]

#: Largest coordinate magnitude accepted: the solver squares and sums coordinates, and
#: values near 1e300 overflow to infinity there (the job would fail much later with
#: "W is zero after centring").
MAX_COORDINATE = 1e100

TOO_DEEP = (
    "{what} nests arrays or objects too deeply to be read; tracks are F x P x 2 nested lists "
    "and parameters a flat object"
)
HOW_TO_SEND = (
    "send multipart/form-data with a 'file' field (npz, HDF5 or CSV, or a video: mp4, webm "
    "or avi, with an optional 'mask' PNG), an optional 'params' field (a JSON object) and "
    "optionally the camera ('focal' in pixels, or 'intrinsics': K as text), or "
    "application/json with 'tracks' (F x P x 2) and 'params'"
)


@dataclass(frozen=True)
class InputCheck:
    """One upload to check, as the API hands it to the child.

    ``source`` is the upload on disk (the file part, or the JSON body); ``target`` is where
    the normalised input goes (``input.npz`` layout of :func:`moju_core.io.write_measurements`);
    ``camera`` is the camera of the form's ``focal`` or ``intrinsics`` field, which replaces
    the file's K (:mod:`service.camera_fields`).
    """

    source: Path
    kind: InputKind
    target: Path
    max_points: int
    max_frames: int
    worker_memory_bytes: int
    camera: CameraRequest | None = None


@dataclass(frozen=True)
class CheckedInput:
    """What the API needs of a checked input: its sizes and which optional arrays it has."""

    n_frames: int
    n_points: int
    has_rotations: bool
    has_ground_truth: bool
    has_faces: bool
    has_colors: bool
    observed_fraction: float
    #: The parameters of a JSON body (None: none given, or a file upload).
    params: SolverParams | None = None
    #: The camera the input carries once the form's is applied (None: orthographic tracks).
    camera: CameraSummary | None = None


def admit(n_frames: int, n_points: int, *, limit: int) -> None:
    """The solver-memory check, made by the file readers from the headers before reading."""
    feasibility.check_memory(n_frames, n_points, limit, limit_name=WORKER_MEMORY_SETTING)


def _array(name: str, value: Any) -> np.ndarray:
    try:
        return np.asarray(value, dtype=np.float64)
    except ValueError as exc:
        raise MeasurementError(
            f"{name} is not a rectangular array ({exc}); every row needs the same length"
        ) from None


def _measurements_from_json(body: TracksBody) -> Measurements:
    W = tracks_to_W(_array("tracks", body.tracks))  # null coordinates become NaN
    rotations = None if body.rotations is None else _array("rotations", body.rotations)
    truth = None if body.ground_truth is None else _array("ground_truth", body.ground_truth)
    visibility = None
    if body.visibility is not None:
        visibility = _array("visibility", body.visibility).astype(bool)
    return Measurements(W=W, rotations=rotations, ground_truth=truth, visibility=visibility)


def parse_json_body(body: bytes | bytearray) -> tuple[TracksBody, Measurements]:
    """Parse and validate a JSON body (about 16 times its size in memory)."""
    try:
        value = json.loads(body)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InvalidInput(f"the body is not valid JSON ({exc}); {HOW_TO_SEND}") from None
    except RecursionError:
        raise InvalidInput(TOO_DEEP.format(what="the JSON body")) from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits
        raise InvalidInput(f"the JSON body cannot be read: {exc}; {HOW_TO_SEND}") from None
    if not isinstance(value, dict):
        raise InvalidInput(f"the JSON body must be an object; {HOW_TO_SEND}")
    try:
        # Strict: "5" or true are not numbers, "1.5" is not a coordinate.
        parsed = TracksBody.model_validate(value, strict=True)
    except ValidationError as exc:
        raise InvalidInput(describe_errors(exc.errors(), parameters_at="params")) from None
    del value
    return parsed, _measurements_from_json(parsed)


def _json_input(check: InputCheck) -> tuple[Measurements, SolverParams | None]:
    parsed, measurements = parse_json_body(check.source.read_bytes())
    n_frames, n_points = measurements.n_frames, measurements.n_points
    if n_points > check.max_points or n_frames > check.max_frames:
        raise MeasurementTooLarge(
            f"the tracks hold {n_frames} frames x {n_points} points; the limit is "
            f"{check.max_frames} frames and {check.max_points} points. Send fewer frames "
            "or subsample the points"
        )
    admit(n_frames, n_points, limit=check.worker_memory_bytes)
    return measurements, parsed.params


def _file_input(check: InputCheck) -> Measurements:
    # Opened through its descriptor: messages then speak of "the uploaded file", never of
    # the server's temporary path.
    with open(check.source, "rb") as opened, io.FileIO(opened.fileno(), closefd=False) as raw:
        return read_measurements(
            io.BufferedReader(raw),
            format=check.kind,
            max_points=check.max_points,
            max_frames=check.max_frames,
            admit=functools.partial(admit, limit=check.worker_memory_bytes),
        )


def check_magnitude(measurements: Measurements) -> None:
    """Refuse coordinates beyond :data:`MAX_COORDINATE` in W (or the ground truth)."""
    for name, values in (("W", measurements.W), ("gt", measurements.ground_truth)):
        if values is None or values.size == 0:
            continue
        largest = max(abs(float(np.nanmin(values))), abs(float(np.nanmax(values))))
        if largest > MAX_COORDINATE:
            raise MeasurementError(
                f"{name} holds coordinates as large as {largest:.3g}; the solver squares them, "
                f"so they must stay within {MAX_COORDINATE:g} in magnitude. Rescale the "
                "tracks (e.g. to pixels, or to a unit scale)"
            )


def check_input(check: InputCheck) -> CheckedInput:
    """Read and validate ``check.source``; write the normalised input to ``check.target``.

    Raises
    ------
    MeasurementTooLarge
        A size above the limits, from the headers (413).
    MeasurementError, InvalidInput
        Anything unusable (422).
    MemoryError
        The process's memory limit was reached (413, see :mod:`service.check_process`).
    """
    params = None
    if check.kind == "json":
        measurements, params = _json_input(check)
    else:
        measurements = _file_input(check)
    check_magnitude(measurements)
    camera = apply_camera(check.camera, measurements, "the uploaded file")
    write_measurements(check.target, measurements)
    return CheckedInput(
        n_frames=measurements.n_frames,
        n_points=measurements.n_points,
        has_rotations=measurements.rotations is not None,
        has_ground_truth=measurements.ground_truth is not None,
        has_faces=measurements.faces is not None,
        has_colors=measurements.colors is not None,
        observed_fraction=measurements.observed_fraction,
        params=params,
        camera=camera,
    )
