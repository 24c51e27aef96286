"""Reading measurements and writing results: the file contract shared by the CLI, API and worker.

Input files (npz, HDF5 or CSV) may come from strangers, so readers never unpickle, look at the
declared shape and dtype of every dataset before reading its data, refuse sizes above the
caller's limits, and turn every failure of the underlying libraries into a
:class:`~moju_core.errors.MeasurementError` that says what is wrong.

Dataset names of an input file (npz members or HDF5 root datasets):

* ``W`` (2F x P): rows 2f, 2f+1 are x, y of frame f; or ``tracks`` (F x P x 2). A point that
  is not observed in a frame is NaN there (x and y both);
* optional ``visibility`` (F x P bool, True = observed), which must agree with the NaN of W;
* optional ``R`` (F x 2 x 3) known rotations, ``gt`` (F x P x 3) ground truth,
  ``faces`` (M x 3) triangle indices, ``colors`` (P x 3, or P x 4 with alpha) in 0..255.

Other datasets are ignored. A CSV input is in long format with the header ``frame,point,x,y``,
one row per observed (frame, point) pair: a missing row is a point not observed in that frame.
Every point must be observed in at least 2 frames and every frame must observe at least 3
points (:func:`moju_core.validation.check_observations`).

Result files hold ``shapes`` (F x P x 3, every point in every frame, the unobserved ones
filled in by the solver), ``visibility`` (F x P bool, the observations used), ``rotations``
(F x 2 x 3), ``labels`` (P,), the per-iteration history and the metadata; every result is
written to a temporary file and renamed into place, so a crash never leaves a half-written file
under the final name.
"""

from __future__ import annotations

import codecs
import contextlib
import csv
import functools
import io
import json
import os
import uuid
import zipfile
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import h5py
import numpy as np
import numpy.lib.format as npy_format

from moju_core import __version__
from moju_core.errors import MeasurementError, MeasurementTooLarge
from moju_core.result import Result
from moju_core.validation import (
    check_colors,
    check_dtype,
    check_faces,
    check_ground_truth,
    check_observation_counts,
    check_observations,
    check_rotations,
    tracks_to_W,
)

__all__ = [
    "FORMATS",
    "Measurements",
    "ResultFile",
    "atomic_output",
    "read_measurements",
    "read_result",
    "write_measurements",
    "write_result",
]

PathLike = str | os.PathLike
Source = str | os.PathLike | IO[bytes]
#: Called with (F, P) once a file's sizes are known and before its data is read; raises
#: MeasurementTooLarge (or another MeasurementError) to refuse the file.
Admit = Callable[[int, int], None]

#: Input formats understood by :func:`read_measurements`.
FORMATS = ("npz", "h5", "csv")
_FORMAT_ALIASES = {"npz": "npz", "h5": "h5", "hdf5": "h5", "csv": "csv"}
_EXTENSION_FORMATS = {".npz": "npz", ".h5": "h5", ".hdf5": "h5", ".hdf": "h5", ".csv": "csv"}
_ZIP_MAGIC = b"PK\x03\x04"
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
_NPY_MAGIC = b"\x93NUMPY"

_OPTIONAL_NAMES = ("visibility", "R", "gt", "faces", "colors")
_DATASET_NAMES = ("W", "tracks", *_OPTIONAL_NAMES)
_EXPECTED_MAIN = "W (2F x P: rows 2f, 2f+1 are x, y of frame f) or tracks (F x P x 2)"
_CSV_COLUMNS = ("frame", "point", "x", "y")
#: Longest CSV line read (bytes): a row of four numbers and a few extra columns fits easily,
#: and a file without line breaks is refused without being held in memory.
_CSV_MAX_LINE_BYTES = 4096
#: Bytes of CSV text parsed at once; the reader never holds much more text than this.
_CSV_BLOCK_BYTES = 2**20
# A triangulated surface of P vertices has about 2P triangles; 4P leaves room for any honest
# mesh while bounding what a hostile file can make us read.
_MAX_FACES_PER_POINT = 4

_RESULT_EXTENSIONS = {".npz": "npz", ".h5": "h5", ".hdf5": "h5"}
_HISTORY_PREFIX = "history_"
_RESULT_ARRAYS = ("shapes", "rotations", "labels")
#: Optional in a result file: files written before it existed lack it.
_RESULT_VISIBILITY = "visibility"
_RESULT_JSON = ("params", "timings", "metadata")


# --------------------------------------------------------------------------------------------
# Measurements


@dataclass
class Measurements:
    """Validated input of one reconstruction.

    Every field is checked and converted on construction (:mod:`moju_core.validation`).

    Attributes
    ----------
    W : ndarray of shape (2F, P), float64
        Rows ``2f`` and ``2f+1`` are the x and y image coordinates of frame ``f``; NaN (x and
        y) where a point is not observed in a frame.
    visibility : ndarray of shape (F, P), bool, or None
        True where point ``j`` is observed in frame ``f``; None when every point is observed
        in every frame. When given on construction it must agree with the NaN of W; when left
        out it is derived from them.
    rotations : ndarray of shape (F, 2, 3), float64, or None
        Known camera rotations (orthonormal rows).
    ground_truth : ndarray of shape (F, P, 3), float64, or None
        True 3D shapes, for evaluation.
    faces : ndarray of shape (M, 3), int64, or None
        Triangle indices into the points, for mesh export.
    colors : ndarray of shape (P, 3) or (P, 4), uint8, or None
        Per-point RGB (or RGBA) colours, for mesh export.
    """

    W: np.ndarray
    rotations: np.ndarray | None = None
    ground_truth: np.ndarray | None = None
    faces: np.ndarray | None = None
    colors: np.ndarray | None = None
    visibility: np.ndarray | None = None

    def __post_init__(self) -> None:
        W, visibility = check_observations(self.W, self.visibility)
        if visibility.all():
            self.W, self.visibility = W, None
        else:  # W is a new array here (zeros filled in): mark the unobserved entries again
            W[np.repeat(~visibility, 2, axis=0)] = np.nan
            self.W, self.visibility = W, visibility
        n_frames, n_points = self.n_frames, self.n_points
        if self.rotations is not None:
            self.rotations = check_rotations(self.rotations, n_frames)
        if self.ground_truth is not None:
            self.ground_truth = check_ground_truth(self.ground_truth, n_frames, n_points)
        if self.faces is not None:
            self.faces = check_faces(self.faces, n_points)
        if self.colors is not None:
            self.colors = check_colors(self.colors, n_points)

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return self.W.shape[0] // 2

    @property
    def n_points(self) -> int:
        """Number of points P."""
        return self.W.shape[1]

    @property
    def observed_fraction(self) -> float:
        """Fraction of the F x P (frame, point) entries that are observed, in (0, 1]."""
        return 1.0 if self.visibility is None else float(self.visibility.mean())


class _LeavesFile(Exception):
    """An HDF5 path crosses a link to another file (internal to the HDF5 reader)."""


#: Soft links followed one after the other before a path counts as a loop.
_MAX_SOFT_LINK_HOPS = 32


@dataclass(frozen=True)
class _Declared:
    """Shape and dtype a file declares for one dataset, and how to read its data."""

    shape: tuple[int, ...]
    dtype: np.dtype
    read: Callable[[], np.ndarray]


def _source_name(source: Source) -> str:
    # Only the base name: an error message must not reveal the server's directory layout.
    if isinstance(source, (str, os.PathLike)):
        return Path(source).name
    name = getattr(source, "name", None)
    return Path(name).name if isinstance(name, str) and name else "the uploaded file"


@contextlib.contextmanager
def _binary_input(source: Source, source_name: str) -> Iterator[IO[bytes]]:
    """Yield a seekable binary file positioned at the start of ``source``."""
    if isinstance(source, (str, os.PathLike)):
        try:
            handle = open(source, "rb")
        except OSError as exc:
            raise MeasurementError(f"could not open {source_name}: {exc.strerror}") from exc
        with handle:
            yield handle
        return
    if not (hasattr(source, "seekable") and source.seekable()):
        # zipfile and h5py need to seek; a pipe or socket is buffered in memory.
        yield io.BytesIO(source.read())
        return
    source.seek(0)
    yield source


def _detect_format(handle: IO[bytes], source: Source, source_name: str) -> str:
    magic = handle.read(8)
    handle.seek(0)
    if magic.startswith(_ZIP_MAGIC):
        return "npz"
    if magic.startswith(_HDF5_MAGIC):
        return "h5"
    if magic.startswith(_NPY_MAGIC):
        raise MeasurementError(
            f"{source_name} is a .npy file (one bare array); save the tracks in an npz with a "
            "name, e.g. np.savez(path, W=W)"
        )
    name = source if isinstance(source, (str, os.PathLike)) else getattr(source, "name", None)
    suffix = Path(name).suffix.lower() if isinstance(name, (str, os.PathLike)) else ""
    return _EXTENSION_FORMATS.get(suffix, "csv")


def _check_limit(limit: int | None, what: str) -> None:
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 1):
        raise ValueError(f"{what} limit must be a positive integer or None, got {limit!r}")


def _refuse_oversized(
    source_name: str,
    origin: str,
    n_frames: int,
    n_points: int,
    max_frames: int | None,
    max_points: int | None,
) -> None:
    too_many_frames = max_frames is not None and n_frames > max_frames
    too_many_points = max_points is not None and n_points > max_points
    if too_many_frames or too_many_points:
        limits = []
        if max_frames is not None:
            limits.append(f"{max_frames} frames")
        if max_points is not None:
            limits.append(f"{max_points} points")
        raise MeasurementTooLarge(
            f"{source_name} holds {n_frames} frames x {n_points} points ({origin}); the limit "
            f"is {' and '.join(limits)}. Send fewer frames or subsample the points"
        )


def _main_size(name: str, declared: _Declared) -> tuple[int, int]:
    """(F, P) declared by the W or tracks header; the exact checks come after reading."""
    shape = declared.shape
    if name == "W":
        if len(shape) != 2:
            raise MeasurementError(
                f"W has shape {shape} ({len(shape)}-D); it needs shape (2F, P) with rows 2f, "
                "2f+1 the x, y of frame f"
            )
        return (shape[0] + 1) // 2, shape[1]
    if len(shape) != 3 or shape[2] != 2:
        raise MeasurementError(
            f"tracks has shape {shape}; it needs shape (F, P, 2): the (x, y) position of every "
            "point in every frame"
        )
    return shape[0], shape[1]


def _largest_allowed(name: str, n_frames: int, n_points: int, max_points: int | None) -> int:
    """Most elements a well-formed optional dataset can hold for F frames and P points."""
    if name == "R":
        return 6 * n_frames
    if name == "visibility":
        return n_frames * n_points
    if name == "gt":
        return 3 * n_frames * n_points
    if name == "colors":
        return 4 * n_points
    if max_points is None:  # faces: only bounded when the caller sets limits
        return -1
    return 3 * _MAX_FACES_PER_POINT * max_points


def _measurements_from_declared(
    declared: Mapping[str, _Declared],
    source_name: str,
    max_frames: int | None,
    max_points: int | None,
    admit: Admit | None = None,
) -> Measurements:
    """Check headers, read the datasets and validate them into :class:`Measurements`."""
    if "W" in declared and "tracks" in declared:
        raise MeasurementError(
            f"{source_name} holds both W and tracks; keep one of them, the two would disagree"
        )
    main = "W" if "W" in declared else "tracks" if "tracks" in declared else None
    if main is None:
        raise MeasurementError(
            f"{source_name} has no dataset named W or tracks; store the measurements as "
            f"{_EXPECTED_MAIN}"
        )
    check_dtype(main, declared[main].dtype)
    n_frames, n_points = _main_size(main, declared[main])
    origin = f"{main} declares shape {declared[main].shape}"
    _refuse_oversized(source_name, origin, n_frames, n_points, max_frames, max_points)
    if admit is not None:
        admit(n_frames, n_points)
    for name in _OPTIONAL_NAMES:
        if name not in declared:
            continue
        if not (name == "visibility" and declared[name].dtype.kind == "b"):
            integer = name in ("visibility", "faces", "colors")
            check_dtype(name, declared[name].dtype, integer=integer)
        size = int(np.prod(declared[name].shape, dtype=object))
        largest = _largest_allowed(name, n_frames, n_points, max_points)
        if largest >= 0 and size > largest:
            raise MeasurementError(
                f"{name} in {source_name} declares shape {declared[name].shape}, more values "
                f"than {n_frames} frames and {n_points} points allow; check that it belongs to "
                f"this {main}"
            )
    arrays = {name: declared[name].read() for name in _DATASET_NAMES if name in declared}
    W = arrays["W"] if main == "W" else tracks_to_W(arrays["tracks"])
    return Measurements(
        W=W,
        rotations=arrays.get("R"),
        ground_truth=arrays.get("gt"),
        faces=arrays.get("faces"),
        colors=arrays.get("colors"),
        visibility=arrays.get("visibility"),
    )


def _npz_header(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> tuple[tuple, np.dtype, int]:
    """Shape, dtype and data offset from a member's .npy header, without reading the data."""
    with archive.open(info) as member:
        version = npy_format.read_magic(member)
        if version == (1, 0):
            shape, _, dtype = npy_format.read_array_header_1_0(member)
        elif version in ((2, 0), (3, 0)):
            # 3.0 only allows UTF-8 in structured field names, which are refused anyway.
            shape, _, dtype = npy_format.read_array_header_2_0(member)
        else:
            raise ValueError(f"unsupported .npy format version {version}")
        return tuple(shape), dtype, member.tell()


def _read_npz_member(
    archive: zipfile.ZipFile, info: zipfile.ZipInfo, declared_bytes: int, source_name: str
) -> np.ndarray:
    """Read one .npy member whose header promised ``declared_bytes`` (header included)."""
    # A header may promise far more than the member holds; numpy would allocate the promised
    # size before noticing.
    if info.file_size < declared_bytes:
        raise MeasurementError(
            f"{info.filename} in {source_name} is truncated: its header declares "
            f"{declared_bytes} bytes but the member holds {info.file_size}"
        )
    with archive.open(info) as stream:
        return npy_format.read_array(stream, allow_pickle=False)


def _read_npz(
    handle: IO[bytes],
    source_name: str,
    max_frames: int | None,
    max_points: int | None,
    admit: Admit | None = None,
) -> Measurements:
    try:
        with zipfile.ZipFile(handle) as archive:
            members = {
                info.filename[: -len(".npy")]: info
                for info in archive.infolist()
                if info.filename.endswith(".npy")
            }
            declared = {}
            for name in _DATASET_NAMES:
                if name not in members:
                    continue
                info = members[name]
                shape, dtype, offset = _npz_header(archive, info)
                size = offset + dtype.itemsize * int(np.prod(shape, dtype=object))
                read = functools.partial(_read_npz_member, archive, info, size, source_name)
                declared[name] = _Declared(shape, dtype, read)
            return _measurements_from_declared(declared, source_name, max_frames, max_points, admit)
    except MeasurementError:
        raise
    except Exception as exc:
        # zipfile, zlib and numpy raise a zoo of types on corrupt input; report them as one.
        raise MeasurementError(
            f"could not read {source_name} as npz: {exc}. Check that the file is complete and "
            "was written with numpy.savez"
        ) from exc


def _h5_resolve(h5: h5py.File, path: str, hops: int = 0) -> str | None:
    """``path`` with every soft link on it followed: a path of hard links only, or None
    when nothing is there.

    Raises ``_LeavesFile`` when the path crosses a link to another file (external or
    user-defined) at any depth, through soft links too, or loops.
    """
    if hops > _MAX_SOFT_LINK_HOPS:
        raise _LeavesFile("soft links that loop")
    current = ""
    for part in (part for part in path.split("/") if part and part != "."):
        group = h5[current or "/"]
        if not isinstance(group, h5py.Group):
            return None
        link = group.get(part, getlink=True)
        if link is None:
            return None
        if isinstance(link, h5py.SoftLink):
            target = link.path if link.path.startswith("/") else f"{current}/{link.path}"
            resolved = _h5_resolve(h5, target, hops + 1)
            if resolved is None:
                return None
            current = resolved
        elif isinstance(link, h5py.HardLink):
            current = f"{current}/{part}"
        else:
            raise _LeavesFile(f"a link to another file ({type(link).__name__})")
    return current or "/"


def _h5_declared(h5: h5py.File, source_name: str) -> dict[str, _Declared]:
    declared = {}
    for name in _DATASET_NAMES:
        try:
            path = _h5_resolve(h5, name)
        except _LeavesFile as exc:
            raise MeasurementError(
                f"{name} in {source_name} is a link to another file, or leads to one through "
                f"{exc}; store the data in the file itself"
            ) from None
        if path is None:
            if h5.get(name, getlink=True) is not None:  # a soft link to nothing
                raise MeasurementError(
                    f"{name} in {source_name} is a link to nothing; {name} must be a plain "
                    "array at the root of the file"
                )
            continue
        dataset = h5.get(path)
        if isinstance(dataset, h5py.Group):
            raise MeasurementError(
                f"{name} in {source_name} is an HDF5 group; {name} must be a dataset (a plain "
                "array) at the root of the file"
            )
        if not isinstance(dataset, h5py.Dataset):
            raise MeasurementError(
                f"{name} in {source_name} is not a dataset; {name} must be a plain array at the "
                "root of the file"
            )
        # Virtual and external datasets read other files of the machine that opens them.
        if dataset.is_virtual or dataset.external:
            raise MeasurementError(
                f"{name} in {source_name} refers to data in other files; store the data in the "
                "file itself"
            )
        if dataset.shape is None:
            raise MeasurementError(f"{name} in {source_name} is an empty (null) dataset")
        declared[name] = _Declared(
            tuple(dataset.shape), dataset.dtype, lambda dataset=dataset: dataset[()]
        )
    return declared


def _read_h5(
    source: Source,
    handle: IO[bytes],
    source_name: str,
    max_frames: int | None,
    max_points: int | None,
    admit: Admit | None = None,
) -> Measurements:
    # A path lets HDF5 use its own file driver, which is faster than going through Python.
    target = source if isinstance(source, (str, os.PathLike)) else handle
    try:
        with h5py.File(target, "r") as h5:
            declared = _h5_declared(h5, source_name)
            return _measurements_from_declared(declared, source_name, max_frames, max_points, admit)
    except MeasurementError:
        raise
    except Exception as exc:
        raise MeasurementError(
            f"could not read {source_name} as HDF5: {exc}. Check that the file is complete"
        ) from exc


def _locate_csv_error(
    lines: list[tuple[int, str]], columns: list[int], source_name: str
) -> str | None:
    """Find the first of the numbered ``lines`` the fast parser refused and say what is
    wrong with it."""
    names = dict(zip(columns, _CSV_COLUMNS, strict=True))
    for line_number, line in lines:
        try:
            cells = next(csv.reader([line]))
        except csv.Error as exc:  # e.g. a lone carriage return inside a field
            return f"line {line_number} of {source_name} is not valid CSV: {exc}"
        if len(cells) <= max(columns):
            return (
                f"line {line_number} of {source_name} has {len(cells)} column(s); the header "
                f"needs at least {max(columns) + 1} (frame, point, x, y)"
            )
        for column in columns:
            try:
                float(cells[column])
            except ValueError:
                return (
                    f"line {line_number} of {source_name}, column {names[column]}: "
                    f"{cells[column][:40]!r} is not a number"
                )
    return None


def _describe_pairs(linear: np.ndarray, n_points: int, limit: int = 5) -> str:
    pairs = [f"(frame {i // n_points}, point {i % n_points})" for i in linear[:limit].tolist()]
    return ", ".join(pairs) + (", ..." if linear.size > limit else "")


def _repeated_pairs(linear: np.ndarray, n_frames: int, n_points: int, source_name: str) -> str:
    """Say which (frame, point) pairs occur in more than one CSV row."""
    present, counts = np.unique(linear, return_counts=True)
    repeated = present[counts > 1]
    return (
        f"{source_name} must hold each (frame, point) pair of {n_frames} frames x {n_points} "
        f"points at most once; {repeated.size} are repeated, e.g. "
        f"{_describe_pairs(repeated, n_points)}. Keep one row per observed point and frame"
    )


def _csv_line(handle: IO[bytes], line_number: int, source_name: str) -> str | None:
    """The next line of a CSV without its line break (None at the end), at most
    ``_CSV_MAX_LINE_BYTES`` long."""
    start = handle.tell()
    raw = handle.readline(_CSV_MAX_LINE_BYTES + 1)
    if not raw:
        return None
    if len(raw) > _CSV_MAX_LINE_BYTES:
        raise _too_long(line_number, source_name)
    try:
        return raw.decode("utf-8-sig" if line_number == 1 else "utf-8").rstrip("\r\n")
    except UnicodeDecodeError as exc:
        raise MeasurementError(
            f"{source_name} is neither npz, HDF5 nor UTF-8 text (CSV): byte "
            f"{start + exc.start} is not valid UTF-8"
        ) from exc


def _refuse_binary(handle: IO[bytes], source_name: str) -> None:
    """Say that the file is not text when what follows a header-less first line is not
    UTF-8 (a binary file of another kind, more likely than a CSV without a header)."""
    start = handle.tell()
    decoder = codecs.getincrementaldecoder("utf-8")()
    try:
        decoder.decode(handle.read(_CSV_MAX_LINE_BYTES), final=False)
    except UnicodeDecodeError as exc:
        raise MeasurementError(
            f"{source_name} is neither npz, HDF5 nor UTF-8 text (CSV): byte "
            f"{start + exc.start} is not valid UTF-8"
        ) from exc


def _csv_header(handle: IO[bytes], source_name: str) -> list[int]:
    """Read the header line; the column index of frame, point, x and y."""
    header = _csv_line(handle, 1, source_name) or ""
    try:
        cells = next(csv.reader([header]), [])
    except csv.Error as exc:  # e.g. a lone carriage return inside a field
        raise MeasurementError(
            f"the first line of {source_name} is not a valid CSV header ({exc}); it must name "
            "the columns frame,point,x,y"
        ) from exc
    names = [cell.strip().lower() for cell in cells]
    missing = [column for column in _CSV_COLUMNS if column not in names]
    if missing:
        _refuse_binary(handle, source_name)
        raise MeasurementError(
            f"the CSV header of {source_name} lacks column(s) {', '.join(missing)}; the first "
            "line must name the columns frame,point,x,y (any order, extra columns ignored)"
        )
    repeated = [column for column in _CSV_COLUMNS if names.count(column) > 1]
    if repeated:
        raise MeasurementError(
            f"the CSV header of {source_name} names column(s) {', '.join(repeated)} twice; "
            "name each of frame, point, x, y once"
        )
    return [names.index(column) for column in _CSV_COLUMNS]


def _numbered_lines(text: str, first_line: int) -> list[tuple[int, str]]:
    """The non-empty lines of ``text`` with their line numbers in the file."""
    lines = text.split("\n")
    return [(first_line + i, line.rstrip("\r")) for i, line in enumerate(lines) if line.strip()]


def _too_long(line_number: int, source_name: str) -> MeasurementError:
    return MeasurementError(
        f"line {line_number} of {source_name} is longer than {_CSV_MAX_LINE_BYTES} bytes, the "
        "most a CSV line may have here; a row holds frame,point,x,y (and a few extra columns "
        "at most), one row per line"
    )


def _check_line_lengths(part: bytes, first_line: int, source_name: str) -> None:
    breaks = np.flatnonzero(np.frombuffer(part, dtype=np.uint8) == ord("\n"))
    ends = np.append(breaks, len(part))
    lengths = np.diff(ends, prepend=-1)  # each line with its line break
    too_long = np.flatnonzero(lengths > _CSV_MAX_LINE_BYTES)[:1]
    if too_long.size:
        raise _too_long(first_line + int(too_long[0]), source_name)


def _csv_chunks(
    handle: IO[bytes], data_start: int, columns: list[int], source_name: str
) -> Iterator[tuple[np.ndarray, int, str]]:
    """The data rows in blocks of about ``_CSV_BLOCK_BYTES``: (rows x 4 table of frame,
    point, x, y; the file line the block starts at; the block's text). Only one block of text
    is in memory at a time, and no line may be longer than ``_CSV_MAX_LINE_BYTES``."""
    handle.seek(data_start)
    line_number, offset, rest = 2, data_start, b""
    while True:
        block = handle.read(_CSV_BLOCK_BYTES)
        data = rest + block
        if not data:
            return
        cut = data.rfind(b"\n") + 1 if block else len(data)
        part, rest = data[:cut], data[cut:]
        if len(rest) > _CSV_MAX_LINE_BYTES:
            raise _too_long(line_number + part.count(b"\n"), source_name)
        if not part:
            continue
        _check_line_lengths(part, line_number, source_name)
        try:
            text = part.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise MeasurementError(
                f"{source_name} is neither npz, HDF5 nor UTF-8 text (CSV): byte "
                f"{offset + exc.start} is not valid UTF-8"
            ) from exc
        if text.strip():
            try:
                table = np.loadtxt(
                    io.StringIO(text, newline=None),
                    delimiter=",",
                    usecols=columns,
                    dtype=np.float64,
                    ndmin=2,
                    comments=None,
                    quotechar='"',
                )
            except ValueError as exc:
                lines = _numbered_lines(text, line_number)
                message = _locate_csv_error(lines, columns, source_name)
                raise MeasurementError(
                    message or f"could not parse {source_name} as CSV: {exc}"
                ) from exc
            yield table, line_number, text
        line_number += part.count(b"\n")
        offset += len(part)
        if not block:
            return


def _check_csv_indices(
    table: np.ndarray, first_line: int, text: str, n_rows: int | None, source_name: str
) -> None:
    """Frame and point indices are whole and >= 0 (and < ``n_rows`` once it is known)."""
    for column, values in (("frame", table[:, 0]), ("point", table[:, 1])):
        bad = (values != np.floor(values)) | (values < 0)
        if n_rows is not None:
            # Indices >= n_rows cannot belong to a usable file and would overflow F * P.
            bad |= values >= n_rows
        first = np.flatnonzero(bad)[:1]
        if first.size:
            line = _numbered_lines(text, first_line)[first[0]][0]
            raise MeasurementError(
                f"line {line} of {source_name}: {column} is {values[first[0]]:g}; frames and "
                "points must be numbered 0..F-1 and 0..P-1, each with rows of its own"
                + ("" if n_rows is None else f", and the file has {n_rows} rows")
            )


def _read_csv(
    handle: IO[bytes],
    source_name: str,
    max_frames: int | None,
    max_points: int | None,
    admit: Admit | None = None,
) -> Measurements:
    """Read a long-format CSV (frame,point,x,y) in two streamed passes.

    The first pass only counts the rows and finds F and P (one chunk of rows in memory); the
    limits and ``admit`` are checked then, before the second pass builds W (2F, P).
    """
    columns = _csv_header(handle, source_name)
    data_start = handle.tell()
    max_rows = None if max_frames is None or max_points is None else max_frames * max_points
    n_rows, largest = 0, np.zeros(2)
    for table, first_line, text in _csv_chunks(handle, data_start, columns, source_name):
        _check_csv_indices(table, first_line, text, None, source_name)
        n_rows += table.shape[0]
        largest = np.maximum(largest, table[:, :2].max(axis=0))
        if max_rows is not None and n_rows > max_rows:
            raise MeasurementTooLarge(
                f"{source_name} has more than {max_rows} data rows, more than {max_frames} "
                f"frames x {max_points} points (the limit) can fill. Send fewer frames or "
                "subsample the points"
            )
    if n_rows == 0:
        raise MeasurementError(f"{source_name} has a CSV header but no data rows")
    n_frames, n_points = int(largest[0]) + 1, int(largest[1]) + 1
    if n_frames <= n_rows and n_points <= n_rows:  # else the second pass says which line
        origin = "largest frame and point indices of its rows"
        _refuse_oversized(source_name, origin, n_frames, n_points, max_frames, max_points)
        if admit is not None:
            admit(n_frames, n_points)
    # Every frame and point needs rows of its own (3 per frame, 2 per point), so an index
    # >= n_rows cannot belong to a usable file: W is built only within that bound (the second
    # pass names the line otherwise), which also bounds F x P.
    within = n_frames <= n_rows and n_points <= n_rows
    # Pairs without a row are not observed: NaN, as in W of the other formats.
    W = np.full((2 * n_frames, n_points), np.nan) if within else None
    linear = np.empty(n_rows, dtype=np.int64)
    done = 0
    for table, first_line, text in _csv_chunks(handle, data_start, columns, source_name):
        _check_csv_indices(table, first_line, text, n_rows, source_name)
        frames, points = table[:, 0].astype(np.int64), table[:, 1].astype(np.int64)
        linear[done : done + len(frames)] = frames * n_points + points
        done += len(frames)
        if W is not None:
            flat = W.reshape(-1)
            flat[2 * frames * n_points + points] = table[:, 2]
            flat[(2 * frames + 1) * n_points + points] = table[:, 3]
    if W is None or np.unique(linear).size != n_rows:
        raise MeasurementError(_repeated_pairs(linear, n_frames, n_points, source_name))
    if n_frames >= 2 and n_points >= 3:  # else Measurements names the size problem
        check_observation_counts(
            np.bincount(linear % n_points, minlength=n_points),
            np.bincount(linear // n_points, minlength=n_frames),
        )
    return Measurements(W=W)


def read_measurements(
    source: Source,
    *,
    format: str | None = None,
    max_points: int | None = None,
    max_frames: int | None = None,
    admit: Admit | None = None,
) -> Measurements:
    """Read and validate measurements from an npz, HDF5 or CSV file.

    Parameters
    ----------
    source : str, os.PathLike or binary file object
        A path, or an open binary file (an upload) read from its start.
    format : {"npz", "h5", "csv"} or None, default None
        File format (``"hdf5"`` is accepted for ``"h5"``). When None it is detected from the
        first bytes (zip: npz, HDF5 signature: h5), else from the file extension, else CSV.
    max_points, max_frames : int or None, default None
        Largest P and F accepted. They are checked against the sizes a file declares before
        its data is read, so an oversized upload costs no memory.
    admit : callable (F, P) -> None, optional
        Called once the number of frames F and points P is known and before any array of
        that size is built: from the headers for npz and HDF5, after a first streamed pass
        over the rows (one chunk in memory) for CSV. It refuses a file by raising
        :class:`MeasurementTooLarge` (e.g. when the solver's memory estimate is too large).

    Returns
    -------
    Measurements
        W (2F, P) float64 (NaN where a point is not observed), its visibility (None when
        nothing is missing) and the optional datasets found in the file, all validated.

    Raises
    ------
    MeasurementError
        For anything unusable: unreadable or truncated files, missing W/tracks, pickled or
        non-numeric data, groups or links where datasets belong, wrong shapes, sizes above the
        limits, infinite values, NaN in one coordinate only, a visibility that disagrees with
        W, points observed in fewer than 2 frames, frames observing fewer than 3 points,
        repeated CSV rows.
    """
    _check_limit(max_points, "max_points")
    _check_limit(max_frames, "max_frames")
    if format is not None:
        if format.lower() not in _FORMAT_ALIASES:
            raise MeasurementError(
                f"unknown input format {format!r}; use one of {', '.join(FORMATS)}"
            )
        format = _FORMAT_ALIASES[format.lower()]
    source_name = _source_name(source)
    with _binary_input(source, source_name) as handle:
        if format is None:
            format = _detect_format(handle, source, source_name)
        if format == "npz":
            return _read_npz(handle, source_name, max_frames, max_points, admit)
        if format == "h5":
            return _read_h5(source, handle, source_name, max_frames, max_points, admit)
        return _read_csv(handle, source_name, max_frames, max_points, admit)


def _measurement_arrays(measurements: Measurements) -> dict[str, np.ndarray]:
    arrays = {"W": measurements.W}
    optional = {
        "visibility": measurements.visibility,
        "R": measurements.rotations,
        "gt": measurements.ground_truth,
        "faces": measurements.faces,
        "colors": measurements.colors,
    }
    arrays.update({name: value for name, value in optional.items() if value is not None})
    return arrays


def write_measurements(path: PathLike, measurements: Measurements) -> Path:
    """Write measurements in the input file contract (atomically).

    Parameters
    ----------
    path : str or os.PathLike
        Target file; the format follows the extension: ``.npz`` (compressed), ``.h5`` /
        ``.hdf5``, or ``.csv`` (long format ``frame,point,x,y``; W only, one row per observed
        pair).
    measurements : Measurements
        What to write; datasets that are None are left out.

    Returns
    -------
    Path
        The path written.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".h5", ".hdf5", ".csv"):
        raise ValueError(
            f"cannot tell the format of {path.name}: use the extension .npz, .h5, .hdf5 or .csv"
        )
    arrays = _measurement_arrays(measurements)
    # CSV keeps the visibility as its missing rows.
    extra = sorted(set(arrays) - {"W", "visibility"})
    if suffix == ".csv" and extra:
        raise ValueError(
            f"CSV holds only the tracks, not {', '.join(extra)}; write .npz or .h5 to keep them"
        )
    with atomic_output(path) as temporary:
        if suffix == ".npz":
            # Inputs are written once and shipped as examples, so smaller beats faster here.
            with open(temporary, "wb") as handle:
                np.savez_compressed(handle, **arrays)
        elif suffix == ".csv":
            n_frames, n_points = measurements.n_frames, measurements.n_points
            tracks = measurements.W.reshape(n_frames, 2, n_points)
            frame_index, point_index = np.divmod(np.arange(n_frames * n_points), n_points)
            table = np.column_stack(
                [frame_index, point_index, tracks[:, 0].ravel(), tracks[:, 1].ravel()]
            )
            if measurements.visibility is not None:  # unobserved pairs get no row
                table = table[measurements.visibility.ravel()]
            np.savetxt(
                temporary,
                table,
                fmt=["%d", "%d", "%.17g", "%.17g"],
                delimiter=",",
                header=",".join(_CSV_COLUMNS),
                comments="",
            )
        else:
            with h5py.File(temporary, "w") as h5:
                for name, value in arrays.items():
                    h5.create_dataset(name, data=value)
    return path


# --------------------------------------------------------------------------------------------
# Atomic output


@contextlib.contextmanager
def atomic_output(path: PathLike) -> Iterator[Path]:
    """Give a temporary path next to ``path`` that is renamed to ``path`` on success.

    The temporary file is created empty in the same directory (so the rename is atomic on
    POSIX), flushed to disk before the rename, and removed if the ``with`` body raises: no
    half-written file ever appears under the final name, and none is left behind.

    Parameters
    ----------
    path : str or os.PathLike
        Final location of the file.

    Yields
    ------
    Path
        The temporary file to write (it exists, empty; writers may truncate or replace it).
    """
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}.tmp")
    # O_EXCL never clobbers a file; mode 0o666 lets the umask decide the permissions as for any
    # open(), where NamedTemporaryFile would leave the result readable by its owner only.
    os.close(os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    try:
        yield temporary
        descriptor = os.open(temporary, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


# --------------------------------------------------------------------------------------------
# Results


@dataclass
class ResultFile:
    """Contents of a result file written by :func:`write_result`.

    Attributes
    ----------
    shapes : ndarray of shape (F, P, 3), float64
        Per-frame 3D points in the units of the input tracks.
    rotations : ndarray of shape (F, 2, 3), float64
        Per-frame camera rotations.
    labels : ndarray of shape (P,), int64
        Local group of every point.
    history : dict of str to ndarray of shape (n_iter,)
        Per-iteration convergence history (``gap``, ``rho``, ...).
    params : dict
        The solver parameters used (``SolverParams.model_dump()``).
    timings : dict of str to float
        Seconds per stage.
    n_iter : int
        Number of ADMM iterations.
    stop_reason : str
        Why the loop stopped.
    scale : float
        Factor the tracks were divided by before solving.
    version : str
        moju version that wrote the file.
    metadata : dict
        Caller-supplied metadata (job id, input name, ...); empty when none was given.
    visibility : ndarray of shape (F, P), bool, or None
        The observations the solver used: True where point ``j`` was observed in frame
        ``f``; ``shapes`` holds the other entries as filled in by the solver. None for files
        written by versions that did not store it.
    """

    shapes: np.ndarray
    rotations: np.ndarray
    labels: np.ndarray
    history: dict[str, np.ndarray]
    params: dict[str, Any]
    timings: dict[str, float]
    n_iter: int
    stop_reason: str
    scale: float
    version: str
    metadata: dict[str, Any] = field(default_factory=dict)
    visibility: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return self.shapes.shape[0]

    @property
    def n_points(self) -> int:
        """Number of points P."""
        return self.shapes.shape[1]


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _result_contents(
    result: Result, metadata: Mapping[str, Any] | None
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, Any]]:
    """Arrays, history and scalar metadata of a result, checked before any file is touched."""
    shapes = np.ascontiguousarray(result.shapes, dtype=np.float64)
    rotations = np.ascontiguousarray(result.rotations, dtype=np.float64)
    labels = np.ascontiguousarray(result.labels, dtype=np.int64)
    if shapes.ndim != 3 or shapes.shape[2] != 3:
        raise ValueError(f"result.shapes has shape {shapes.shape}; expected (F, P, 3)")
    n_frames, n_points, _ = shapes.shape
    if rotations.shape != (n_frames, 2, 3) or labels.shape != (n_points,):
        raise ValueError(
            f"result.rotations {rotations.shape} and result.labels {labels.shape} do not match "
            f"result.shapes {shapes.shape}: expected ({n_frames}, 2, 3) and ({n_points},)"
        )
    visibility = getattr(result, "visibility", None)
    if visibility is None:  # a solve of complete data
        visibility = np.ones((n_frames, n_points), dtype=bool)
    visibility = np.ascontiguousarray(visibility, dtype=bool)
    if visibility.shape != (n_frames, n_points):
        raise ValueError(
            f"result.visibility {visibility.shape} does not match result.shapes "
            f"{shapes.shape}: expected ({n_frames}, {n_points})"
        )
    history = {}
    for key, values in result.history.items():
        if not key or "/" in key or "\0" in key:
            raise ValueError(f"history key {key!r} cannot be stored; use a plain name")
        history[key] = np.asarray(values)
    scalars = {
        "params": json.dumps(result.params.model_dump(mode="json")),
        "timings": json.dumps(dict(result.timings), default=_json_default),
        "metadata": json.dumps(dict(metadata or {}), default=_json_default),
        "n_iter": int(result.n_iter),
        "stop_reason": str(result.stop_reason),
        "scale": float(result.scale),
        "version": __version__,
    }
    arrays = {
        "shapes": shapes,
        "rotations": rotations,
        "labels": labels,
        _RESULT_VISIBILITY: visibility,
    }
    return arrays, history, scalars


def _result_format(path: Path) -> str:
    try:
        return _RESULT_EXTENSIONS[path.suffix.lower()]
    except KeyError:
        raise ValueError(
            f"cannot tell the result format of {path.name}: use the extension .npz, .h5 or .hdf5"
        ) from None


def write_result(
    path: PathLike, result: Result, *, metadata: Mapping[str, Any] | None = None
) -> Path:
    """Write a reconstruction to an npz or HDF5 file, atomically.

    The data goes to a temporary file in the same directory, which is renamed to ``path`` only
    once complete; on failure it is removed. Large arrays are stored uncompressed: float64
    shapes barely compress and gzip would add seconds for a 70 MB result.

    Parameters
    ----------
    path : str or os.PathLike
        Target file; ``.npz`` or ``.h5`` / ``.hdf5``.
    result : Result
        The reconstruction.
    metadata : mapping, optional
        Extra JSON-serialisable information stored with the result (job id, input name, ...).

    Returns
    -------
    Path
        The path written.

    Notes
    -----
    npz layout: arrays ``shapes``, ``rotations``, ``labels``, ``visibility`` (F x P bool,
    all True when ``result.visibility`` is None), ``history_<key>``, 0-d
    ``n_iter`` (int64) and ``scale`` (float64), 0-d unicode ``stop_reason``, ``version`` and the
    JSON documents ``params``, ``timings``, ``metadata``. HDF5 layout: the same arrays as
    datasets, the history as datasets of group ``history``, the rest as root attributes.
    ``result.extras`` is not stored.
    """
    path = Path(path)
    file_format = _result_format(path)
    arrays, history, scalars = _result_contents(result, metadata)
    with atomic_output(path) as temporary:
        if file_format == "npz":
            members = dict(arrays)
            members.update({_HISTORY_PREFIX + key: value for key, value in history.items()})
            members.update({key: np.asarray(value) for key, value in scalars.items()})
            with open(temporary, "wb") as handle:
                np.savez(handle, **members)
        else:
            with h5py.File(temporary, "w") as h5:
                for name, value in arrays.items():
                    h5.create_dataset(name, data=value)
                group = h5.create_group("history", track_order=True)
                for key, value in history.items():
                    group.create_dataset(key, data=value)
                h5.attrs.update(scalars)
    return path


def _text(value: Any) -> str:
    if isinstance(value, np.ndarray):
        value = value.item()
    return value.decode() if isinstance(value, bytes) else str(value)


def _result_visibility(arrays: Mapping[str, np.ndarray]) -> np.ndarray | None:
    if _RESULT_VISIBILITY not in arrays:
        return None
    visibility = np.asarray(arrays[_RESULT_VISIBILITY], dtype=bool)
    if visibility.shape != arrays["shapes"].shape[:2]:
        raise ValueError(
            f"visibility has shape {visibility.shape}, shapes {arrays['shapes'].shape}"
        )
    return visibility


def read_result(path: PathLike) -> ResultFile:
    """Read a result file written by :func:`write_result` (npz or HDF5, by content).

    Parameters
    ----------
    path : str or os.PathLike
        The result file.

    Returns
    -------
    ResultFile

    Raises
    ------
    ValueError
        When the file cannot be read or lacks a part of the result layout.
    """
    path = Path(path)
    with open(path, "rb") as handle:
        is_hdf5 = handle.read(8) == _HDF5_MAGIC
    try:
        if is_hdf5:
            with h5py.File(path, "r") as h5:
                arrays = {name: h5[name][()] for name in _RESULT_ARRAYS}
                if _RESULT_VISIBILITY in h5:
                    arrays[_RESULT_VISIBILITY] = h5[_RESULT_VISIBILITY][()]
                group = h5.get("history")
                history = {key: group[key][()] for key in group} if group is not None else {}
                scalars = dict(h5.attrs)
        else:
            with np.load(path, allow_pickle=False) as npz:
                arrays = {name: npz[name] for name in _RESULT_ARRAYS}
                if _RESULT_VISIBILITY in npz.files:
                    arrays[_RESULT_VISIBILITY] = npz[_RESULT_VISIBILITY]
                history = {
                    key[len(_HISTORY_PREFIX) :]: npz[key]
                    for key in npz.files
                    if key.startswith(_HISTORY_PREFIX)
                }
                scalars = {
                    key: npz[key]
                    for key in npz.files
                    if key not in arrays and not key.startswith(_HISTORY_PREFIX)
                }
        json_parts = {
            key: json.loads(_text(scalars[key])) if key in scalars else {} for key in _RESULT_JSON
        }
        return ResultFile(
            shapes=np.asarray(arrays["shapes"], dtype=np.float64),
            rotations=np.asarray(arrays["rotations"], dtype=np.float64),
            labels=np.asarray(arrays["labels"], dtype=np.int64),
            history=history,
            params=json_parts["params"],
            timings=json_parts["timings"],
            n_iter=int(scalars["n_iter"]),
            stop_reason=_text(scalars["stop_reason"]),
            scale=float(scalars["scale"]),
            version=_text(scalars["version"]),
            metadata=json_parts["metadata"],
            visibility=_result_visibility(arrays),
        )
    except Exception as exc:  # h5py, zipfile and json each raise their own types
        raise ValueError(
            f"{path.name} is not a readable MoJu result file ({type(exc).__name__}: {exc})"
        ) from exc
