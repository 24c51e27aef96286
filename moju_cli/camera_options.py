"""The camera options ``--intrinsics FILE`` and ``--focal PIXELS`` of ``moju track`` and
``moju reconstruct``, declared once, and how they resolve to an
:class:`~moju_core.cameras.intrinsics.Intrinsics`.

* ``--intrinsics FILE``: the 3 x 3 matrix K in a text file (three lines of three numbers,
  :func:`moju_core.cameras.intrinsics.read_intrinsics`);
* ``--focal PIXELS``: K with that focal length and the principal point at the image centre
  (needs the frame size: a video, or a tracks file with ``frame_size``).

The two are mutually exclusive. Given neither, the input's own K is used (a ``K`` dataset),
else the default camera of its frame size, else none (orthographic tracks).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import click

from moju_core.cameras.intrinsics import Intrinsics, read_intrinsics
from moju_core.errors import MeasurementError

F = TypeVar("F", bound=Callable[..., object])


def intrinsics_options(function: F) -> F:
    """Add ``--intrinsics FILE`` and ``--focal PIXELS`` (parameters ``intrinsics_file`` and
    ``focal``) to a command."""
    function = click.option(
        "--focal",
        type=click.FloatRange(min=0.0, min_open=True),
        default=None,
        metavar="PIXELS",
        help="Focal length of the camera in pixels; the principal point is the image centre "
        "((width - 1) / 2, (height - 1) / 2). Not with --intrinsics.",
    )(function)
    return click.option(
        "--intrinsics",
        "intrinsics_file",
        type=click.Path(exists=True, dir_okay=False, path_type=Path),
        default=None,
        metavar="FILE",
        help="Camera matrix K (pixels) in a text file: three lines of three numbers separated "
        "by commas or spaces. [default: K of the input, else focal 1.2 x the larger image "
        "side for a video or tracks with a frame size]",
    )(function)


@dataclass(frozen=True)
class CameraChoice:
    """What the user asked for on the command line: a matrix, a focal length, or nothing."""

    intrinsics: Intrinsics | None = None
    focal: float | None = None

    @property
    def given(self) -> bool:
        """Whether --intrinsics or --focal was given."""
        return self.intrinsics is not None or self.focal is not None


def camera_choice(intrinsics_file: Path | None, focal: float | None) -> CameraChoice:
    """Check the two options before any work: mutually exclusive, and the file readable as K.

    Raises click.UsageError for both options, click.ClickException for an unusable file.
    """
    if intrinsics_file is not None and focal is not None:
        raise click.UsageError(
            "--intrinsics and --focal both give the camera; use one of them (--intrinsics for "
            "a full matrix K, --focal for a focal length with the principal point at the "
            "image centre)"
        )
    if intrinsics_file is None:
        return CameraChoice(focal=focal)
    try:
        return CameraChoice(intrinsics=read_intrinsics(intrinsics_file))
    except MeasurementError as exc:
        raise click.ClickException(f"--intrinsics: {exc}") from exc


def resolve_intrinsics(
    choice: CameraChoice,
    frame_size: tuple[int, int] | None,
    source_name: str,
) -> Intrinsics | None:
    """The camera of the command line for frames of ``frame_size`` (None: unknown size).

    Returns None when neither option was given (the input's own K, or its default, applies).
    Raises click.UsageError for --focal without a frame size.
    """
    if choice.intrinsics is not None:
        return choice.intrinsics
    if choice.focal is None:
        return None
    if frame_size is None:
        raise click.UsageError(
            f"--focal needs the frame size to put the principal point at the image centre, and "
            f"{source_name} has no frame_size; give the full matrix with --intrinsics FILE, or "
            "add frame_size = (width, height) to the file"
        )
    return Intrinsics.from_focal(choice.focal, frame_size)
