"""The camera's intrinsics: the one definition of K, where it comes from, and its checks.

A pinhole camera maps a point in camera coordinates to pixels through the upper-triangular

    K = [[fx, s,  cx],
         [0,  fy, cy],
         [0,  0,  1 ]]

(focal lengths ``fx``, ``fy`` and skew ``s`` in pixels, principal point ``(cx, cy)`` in
pixels). Pixels follow the tracker's convention: x to the right, y down, the centre of the
top-left pixel at (0, 0), so the centre of a ``width`` x ``height`` image is
``((width - 1) / 2, (height - 1) / 2)``.

Where K comes from, recorded in :attr:`Intrinsics.origin`:

* ``"given"``: a 3 x 3 matrix from the user (a text file, :func:`read_intrinsics`, or the
  ``K`` dataset of a measurement file);
* ``"focal"``: a focal length in pixels, with the principal point at the image centre
  (:meth:`Intrinsics.from_focal`);
* ``"default"``: nothing was given but the frame size is known: COLMAP's default focal
  length, :data:`DEFAULT_FOCAL_FACTOR` x the larger image side, and the principal point at
  the image centre (:meth:`Intrinsics.default_for`);
* ``"estimated"``: the default camera with the focal length the perspective solve found in
  the tracks (:func:`moju_core.priors.focal_length.estimate_focal`,
  :meth:`Intrinsics.with_focal`).

Tracks whose frame size is unknown have no K: they are treated as orthographic, as before.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from moju_core.errors import MeasurementError

__all__ = [
    "DEFAULT_FOCAL_FACTOR",
    "MAX_FRAME_SIDE",
    "MAX_INTRINSICS_BYTES",
    "Intrinsics",
    "IntrinsicsOrigin",
    "check_frame_size",
    "check_intrinsics_matrix",
    "parse_intrinsics",
    "read_intrinsics",
]

#: COLMAP's default focal length, in units of the larger image side (1.2 x max(width, height)
#: pixels): a field of view of about 45 degrees along that side.
DEFAULT_FOCAL_FACTOR = 1.2
#: Largest width or height accepted for a frame size, in pixels: an input limit beyond any
#: camera's sensor, so that a larger number is refused as a mistake.
MAX_FRAME_SIDE = 65_536
#: Largest intrinsics text read, in bytes: three lines of three numbers and comments.
MAX_INTRINSICS_BYTES = 64 * 1024

IntrinsicsOrigin = Literal["given", "focal", "default", "estimated"]
_ORIGINS = ("given", "focal", "default", "estimated")
_FIX_K = (
    "K must be the 3 x 3 upper-triangular camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] "
    "in pixels"
)


def check_frame_size(frame_size: ArrayLike, name: str = "frame_size") -> tuple[int, int]:
    """Validate a frame size.

    Parameters
    ----------
    frame_size : array_like of shape (2,), integers
        (width, height) in pixels, each from 1 to :data:`MAX_FRAME_SIDE`.
    name : str, default "frame_size"
        Name used in messages.

    Returns
    -------
    (int, int)
        (width, height).

    Raises
    ------
    MeasurementError
        When it is not two whole positive numbers within the bound.
    """
    try:
        array = np.asarray(frame_size)
    except (ValueError, TypeError) as exc:
        raise MeasurementError(f"{name} is not an array of two integers ({exc})") from exc
    if array.dtype.kind not in "iu" or array.shape != (2,):
        raise MeasurementError(
            f"{name} has dtype {array.dtype} and shape {array.shape}; it must be two integers "
            "(width, height) in pixels, e.g. np.array([640, 480])"
        )
    width, height = (int(value) for value in array)
    if not (1 <= width <= MAX_FRAME_SIDE and 1 <= height <= MAX_FRAME_SIDE):
        raise MeasurementError(
            f"{name} is {width} x {height}; width and height must be between 1 and "
            f"{MAX_FRAME_SIDE} pixels"
        )
    return width, height


def check_intrinsics_matrix(K: ArrayLike, name: str = "K") -> np.ndarray:
    """Validate a camera matrix.

    Parameters
    ----------
    K : array_like of shape (3, 3), real
        Camera matrix in pixels.
    name : str, default "K"
        Name used in messages (a file name, a dataset name).

    Returns
    -------
    K : ndarray of shape (3, 3), float64
        A new read-only array.

    Raises
    ------
    MeasurementError
        When K is not a finite real 3 x 3 matrix with last row [0, 0, 1], zeros below the
        diagonal and positive focal lengths ``K[0, 0]`` and ``K[1, 1]``.
    """
    try:
        array = np.asarray(K)
    except (ValueError, TypeError) as exc:
        raise MeasurementError(f"{name} is not a 3 x 3 array ({exc}); {_FIX_K}") from exc
    if array.dtype.kind not in "fiu" or array.shape != (3, 3):
        raise MeasurementError(f"{name} has dtype {array.dtype} and shape {array.shape}; {_FIX_K}")
    matrix = array.astype(np.float64)  # a copy, never the caller's array
    if not np.isfinite(matrix).all():
        raise MeasurementError(f"{name} holds NaN or infinite values; {_FIX_K}")
    if not np.array_equal(matrix[2], [0.0, 0.0, 1.0]):
        raise MeasurementError(
            f"the last row of {name} is {matrix[2].tolist()}, not [0, 0, 1]; {_FIX_K} (divide "
            "K by K[2, 2] if it is only scaled)"
        )
    if matrix[1, 0] != 0.0:
        raise MeasurementError(f"{name}[1, 0] is {matrix[1, 0]:g}, not 0; {_FIX_K}")
    if not (matrix[0, 0] > 0.0 and matrix[1, 1] > 0.0):
        raise MeasurementError(
            f"the focal lengths of {name} are fx = {matrix[0, 0]:g} and fy = {matrix[1, 1]:g} "
            f"pixels; both must be positive. {_FIX_K}"
        )
    matrix.flags.writeable = False
    return matrix


def _check_focal(focal_px: float) -> float:
    try:
        focal = float(focal_px)
    except (TypeError, ValueError) as exc:
        raise MeasurementError(f"the focal length {focal_px!r} is not a number") from exc
    if not (np.isfinite(focal) and focal > 0.0):
        raise MeasurementError(
            f"the focal length must be a positive number of pixels, got {focal_px!r}"
        )
    return focal


@dataclass(frozen=True, eq=False)
class Intrinsics:
    """A pinhole camera's intrinsic matrix and where it came from.

    Attributes
    ----------
    K : ndarray of shape (3, 3), float64, read-only
        Upper-triangular camera matrix in pixels (validated on construction, see
        :func:`check_intrinsics_matrix`).
    origin : {"given", "focal", "default", "estimated"}
        How K was chosen: given as a matrix, built from a focal length, the default for the
        frame size, or estimated from the tracks (see the module's description).
    """

    K: np.ndarray
    origin: IntrinsicsOrigin = "given"

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", check_intrinsics_matrix(self.K))
        if self.origin not in _ORIGINS:
            raise ValueError(f"origin must be one of {_ORIGINS}, got {self.origin!r}")

    @classmethod
    def from_focal(cls, focal_px: float, frame_size: ArrayLike) -> Intrinsics:
        """Square pixels, no skew, focal length ``focal_px`` pixels and the principal point at
        the image centre ``((width - 1) / 2, (height - 1) / 2)``.

        Parameters
        ----------
        focal_px : float
            Focal length in pixels (> 0).
        frame_size : array_like of shape (2,), integers
            (width, height) in pixels.
        """
        return cls(_centred(_check_focal(focal_px), check_frame_size(frame_size)), "focal")

    @classmethod
    def default_for(cls, frame_size: ArrayLike) -> Intrinsics:
        """The default camera of a frame size: COLMAP's focal length,
        :data:`DEFAULT_FOCAL_FACTOR` x max(width, height) pixels, principal point at the image
        centre, square pixels, no skew. ``origin`` is ``"default"``."""
        width, height = check_frame_size(frame_size)
        return cls(_centred(DEFAULT_FOCAL_FACTOR * max(width, height), (width, height)), "default")

    def with_focal(self, focal_px: float, origin: IntrinsicsOrigin) -> Intrinsics:
        """This camera with both focal lengths set to ``focal_px`` pixels (square pixels; the
        principal point and skew kept) and the given ``origin``."""
        K = self.K.copy()
        K[0, 0] = K[1, 1] = _check_focal(focal_px)
        return Intrinsics(K, origin)

    @property
    def fx(self) -> float:
        """Focal length along x, pixels."""
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        """Focal length along y, pixels."""
        return float(self.K[1, 1])

    @property
    def principal_point(self) -> tuple[float, float]:
        """(cx, cy) in pixels."""
        return float(self.K[0, 2]), float(self.K[1, 2])

    @property
    def skew(self) -> float:
        """K[0, 1], pixels."""
        return float(self.K[0, 1])

    def normalise(self, W: ArrayLike) -> np.ndarray:
        """Pixel tracks to normalised image coordinates (rays at depth 1): ``inv(K) [u, v, 1]``.

        Parameters
        ----------
        W : array_like of shape (2F, P)
            Rows ``2f`` and ``2f + 1`` are x and y in pixels in frame ``f``; NaN stays NaN.

        Returns
        -------
        rays : ndarray of shape (2F, P), float64
            Rows ``2f``, ``2f + 1``: ``y' = (v - cy) / fy`` and
            ``x' = (u - cx - s y') / fx`` (skew applied in full).
        """
        u, v = _rows(W)
        cx, cy = self.principal_point
        y = (v - cy) / self.fy
        x = (u - cx - self.skew * y) / self.fx
        return _interleave(x, y)

    def to_pixels(self, rays: ArrayLike) -> np.ndarray:
        """The inverse of :meth:`normalise`: rays (2F, P) to pixels (2F, P), NaN kept."""
        x, y = _rows(rays)
        cx, cy = self.principal_point
        return _interleave(self.fx * x + self.skew * y + cx, self.fy * y + cy)

    def to_metadata(self) -> dict[str, Any]:
        """JSON-ready record of the camera: ``{"K": 3 x 3 list, "origin": ...}``."""
        return {"K": self.K.tolist(), "origin": self.origin}

    def __repr__(self) -> str:
        cx, cy = self.principal_point
        return (
            f"Intrinsics(fx={self.fx:g}, fy={self.fy:g}, cx={cx:g}, cy={cy:g}, "
            f"skew={self.skew:g}, origin={self.origin!r})"
        )


def _centred(focal: float, frame_size: tuple[int, int]) -> np.ndarray:
    width, height = frame_size
    return np.array(
        [[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0], [0.0, 0.0, 1.0]]
    )


def _rows(W: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    array = np.asarray(W, dtype=np.float64)
    if array.ndim != 2 or array.shape[0] % 2:
        raise ValueError(f"W must have shape (2F, P), got {array.shape}")
    return array[0::2], array[1::2]


def _interleave(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    out = np.empty((2 * x.shape[0], x.shape[1]))
    out[0::2], out[1::2] = x, y
    return out


def read_intrinsics(path: str | os.PathLike) -> Intrinsics:
    """Read K from a text file: three lines of three numbers, separated by commas or spaces.

    Blank lines and lines starting with ``#`` are skipped, e.g.::

        528.0144, 0, 320
        0, 528.0144, 240
        0, 0, 1

    Parameters
    ----------
    path : str or os.PathLike
        The text file (at most 64 KiB; only that much is read).

    Returns
    -------
    Intrinsics
        With ``origin`` ``"given"``.

    Raises
    ------
    MeasurementError
        When the file cannot be read, or its text is not K (:func:`parse_intrinsics`).
    """
    name = Path(path).name
    try:
        with open(path, "rb") as handle:
            raw = handle.read(MAX_INTRINSICS_BYTES + 1)
    except OSError as exc:
        raise MeasurementError(f"could not read {name}: {exc.strerror or exc}") from exc
    return parse_intrinsics(raw, name)


def parse_intrinsics(raw: bytes, name: str = "the intrinsics") -> Intrinsics:
    """K from the bytes of an intrinsics text file (an upload), as :func:`read_intrinsics`.

    Parameters
    ----------
    raw : bytes
        UTF-8 text, at most :data:`MAX_INTRINSICS_BYTES`.
    name : str
        Name used in messages (a file name, a form field).

    Raises
    ------
    MeasurementError
        When the text is too long, not UTF-8, not three rows of three numbers, or K is not a
        valid camera matrix (:func:`check_intrinsics_matrix`).
    """
    if len(raw) > MAX_INTRINSICS_BYTES:
        raise MeasurementError(
            f"{name} is larger than {MAX_INTRINSICS_BYTES // 1024} KiB; an intrinsics file "
            "holds three lines of three numbers"
        )
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise MeasurementError(
            f"{name} is not a text file ({exc.reason}); write K as three lines of three numbers"
        ) from exc
    rows = []
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        cells = [cell for cell in re.split(r"[,\s;]+", line) if cell]
        try:
            rows.append([float(cell) for cell in cells])
        except ValueError:
            raise MeasurementError(
                f"{name}: the line {line[:60]!r} is not a row of numbers; write K as three "
                "lines of three numbers separated by commas or spaces"
            ) from None
    if len(rows) != 3 or any(len(row) != 3 for row in rows):
        raise MeasurementError(
            f"{name} holds {len(rows)} row(s) of {sorted({len(row) for row in rows})} numbers; "
            "write K as three lines of three numbers separated by commas or spaces, e.g. "
            "'fx, 0, cx' / '0, fy, cy' / '0, 0, 1'"
        )
    return Intrinsics(check_intrinsics_matrix(rows, name=name), "given")
