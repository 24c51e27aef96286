"""PLY export of reconstructed shapes (one file per frame), written with the ``plyfile`` package.

A frame becomes a ``vertex`` element with float32 ``x``, ``y``, ``z`` (plus uchar ``red``,
``green``, ``blue`` and optionally ``alpha`` when colours are given) and, when triangles are
given, a ``face`` element whose ``vertex_indices`` are lists of three int32.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import ArrayLike
from plyfile import PlyData, PlyElement

from moju_core.errors import MeasurementError
from moju_core.io import atomic_output
from moju_core.validation import check_colors, check_dtype, check_faces

__all__ = ["frame_file_name", "ply_bytes", "read_ply_points", "write_ply", "write_ply_frames"]

_CHANNELS = ("red", "green", "blue", "alpha")


def _check_points(points: ArrayLike, name: str = "points") -> np.ndarray:
    points = np.asarray(points)
    check_dtype(name, points.dtype)
    if points.ndim != 2 or points.shape[1] != 3:
        raise MeasurementError(f"{name} has shape {points.shape}; it needs shape (P, 3)")
    if not np.isfinite(points).all():
        raise MeasurementError(f"{name} holds NaN or infinite coordinates; PLY needs finite ones")
    return points


class _FrameWriter:
    """Builds PLY bytes for many frames sharing the same faces and colours (checked once)."""

    def __init__(self, n_points: int, faces: ArrayLike | None, colors: ArrayLike | None) -> None:
        fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
        if colors is not None:
            colors = check_colors(colors, n_points)
            fields += [(channel, "u1") for channel in _CHANNELS[: colors.shape[1]]]
        self._vertices = np.empty(n_points, dtype=fields)
        if colors is not None:
            for index, channel in enumerate(_CHANNELS[: colors.shape[1]]):
                self._vertices[channel] = colors[:, index]
        self._face_element = None
        if faces is not None:
            faces = check_faces(faces, n_points)
            # A fixed-size subarray field is written by plyfile as a list property of length 3.
            face_records = np.empty(len(faces), dtype=[("vertex_indices", "<i4", (3,))])
            face_records["vertex_indices"] = faces
            self._face_element = PlyElement.describe(
                face_records,
                "face",
                len_types={"vertex_indices": "u1"},
                val_types={"vertex_indices": "i4"},
            )
        # Binary frames differ only in the vertex block; see __call__.
        self._header: bytes | None = None
        self._tail = b""

    def _encode(self, binary: bool) -> bytes:
        elements = [PlyElement.describe(self._vertices, "vertex")]
        if self._face_element is not None:
            elements.append(self._face_element)
        buffer = io.BytesIO()
        PlyData(elements, text=not binary, byte_order="<").write(buffer)
        return buffer.getvalue()

    def __call__(self, points: np.ndarray, *, binary: bool = True) -> bytes:
        self._vertices["x"] = points[:, 0]
        self._vertices["y"] = points[:, 1]
        self._vertices["z"] = points[:, 2]
        if not binary:
            return self._encode(binary=False)
        if self._header is not None:
            return self._header + self._vertices.tobytes() + self._tail
        data = self._encode(binary=True)
        # plyfile writes list properties one row at a time (0.1 s for 60k triangles), while the
        # header and the face block are the same for every frame. Reuse them from the first
        # frame's plyfile output, but only after checking that its vertex block is exactly our
        # packed little-endian records; otherwise keep using plyfile for every frame.
        header_end = data.find(b"end_header\n") + len(b"end_header\n")
        vertex_block = self._vertices.tobytes()
        if data[header_end : header_end + len(vertex_block)] == vertex_block:
            self._header = data[:header_end]
            self._tail = data[header_end + len(vertex_block) :]
        return data


def ply_bytes(
    points: ArrayLike,
    *,
    faces: ArrayLike | None = None,
    colors: ArrayLike | None = None,
    binary: bool = True,
) -> bytes:
    """Encode one point set (and optionally its triangles and colours) as a PLY file.

    Parameters
    ----------
    points : array_like of shape (P, 3), float
        Vertex coordinates (stored as float32).
    faces : array_like of shape (M, 3), integer, optional
        Triangle indices into ``points`` (0-based).
    colors : array_like of shape (P, 3) or (P, 4), integer in 0..255, optional
        Per-vertex RGB or RGBA.
    binary : bool, default True
        Binary little-endian PLY; ASCII when False.

    Returns
    -------
    bytes
        The complete PLY file.
    """
    points = _check_points(points)
    return _FrameWriter(len(points), faces, colors)(points, binary=binary)


def write_ply(
    path: str | os.PathLike,
    points: ArrayLike,
    *,
    faces: ArrayLike | None = None,
    colors: ArrayLike | None = None,
    binary: bool = True,
) -> Path:
    """Write one point set as a PLY file (atomically); see :func:`ply_bytes` for the arguments.

    Returns
    -------
    Path
        The path written.
    """
    data = ply_bytes(points, faces=faces, colors=colors, binary=binary)
    path = Path(path)
    with atomic_output(path) as temporary:
        temporary.write_bytes(data)
    return path


def frame_file_name(frame: int, n_frames: int) -> str:
    """Name of frame ``frame``'s PLY file: ``frame_0007.ply``, zero-padded to >= 4 digits."""
    width = max(4, len(str(max(n_frames - 1, 0))))
    return f"frame_{frame:0{width}d}.ply"


def write_ply_frames(
    directory: str | os.PathLike,
    shapes: ArrayLike,
    *,
    faces: ArrayLike | None = None,
    colors: ArrayLike | None = None,
) -> list[Path]:
    """Write every frame of a reconstruction as a binary PLY file.

    Parameters
    ----------
    directory : str or os.PathLike
        Output directory, created if missing.
    shapes : array_like of shape (F, P, 3), float
        Per-frame 3D points.
    faces : array_like of shape (M, 3), integer, optional
        Triangles shared by all frames.
    colors : array_like of shape (P, 3) or (P, 4), integer in 0..255, optional
        Per-point colours shared by all frames.

    Returns
    -------
    list of Path
        ``directory / "frame_0000.ply"`` ... in frame order.
    """
    shapes = np.asarray(shapes)
    if shapes.ndim != 3 or shapes.shape[2] != 3:
        raise MeasurementError(f"shapes has shape {shapes.shape}; it needs shape (F, P, 3)")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    n_frames, n_points, _ = shapes.shape
    encode = _FrameWriter(n_points, faces, colors)
    paths = []
    for frame in range(n_frames):
        data = encode(_check_points(shapes[frame], f"shapes[{frame}]"))
        path = directory / frame_file_name(frame, n_frames)
        with atomic_output(path) as temporary:
            temporary.write_bytes(data)
        paths.append(path)
    return paths


def read_ply_points(source: str | os.PathLike | IO[bytes] | bytes) -> np.ndarray:
    """Read the vertex coordinates of a PLY file.

    Parameters
    ----------
    source : str, os.PathLike, binary file object or bytes
        The PLY file (binary or ASCII).

    Returns
    -------
    points : ndarray of shape (P, 3), float64
    """
    if isinstance(source, (bytes, bytearray)):
        source = io.BytesIO(source)
    try:
        ply = PlyData.read(source)
        vertices = ply["vertex"].data
        return np.column_stack([vertices[axis] for axis in "xyz"]).astype(np.float64)
    except Exception as exc:  # plyfile raises several types on malformed input
        raise MeasurementError(f"could not read the PLY vertices x, y, z: {exc}") from exc
