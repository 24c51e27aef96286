"""The CSV reader (long format ``frame,point,x,y``): two streamed passes, bounded lines."""

from __future__ import annotations

import codecs
import csv
import io
from collections.abc import Iterator
from typing import IO

import numpy as np

from moju_core.errors import MeasurementError, MeasurementTooLarge
from moju_core.io._sources import Admit, ShortTracks, refuse_oversized
from moju_core.io.measurements import Measurements
from moju_core.validation import check_observation_counts

CSV_COLUMNS = ("frame", "point", "x", "y")
#: Longest CSV line read (bytes): a row of four numbers and a few extra columns fits easily,
#: and a file without line breaks is refused without being held in memory.
_CSV_MAX_LINE_BYTES = 4096
#: Bytes of CSV text parsed at once; the reader never holds much more text than this.
_CSV_BLOCK_BYTES = 2**20


def _locate_csv_error(
    lines: list[tuple[int, str]], columns: list[int], source_name: str
) -> str | None:
    """Find the first of the numbered ``lines`` the fast parser refused and say what is
    wrong with it."""
    names = dict(zip(columns, CSV_COLUMNS, strict=True))
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
    missing = [column for column in CSV_COLUMNS if column not in names]
    if missing:
        _refuse_binary(handle, source_name)
        raise MeasurementError(
            f"the CSV header of {source_name} lacks column(s) {', '.join(missing)}; the first "
            "line must name the columns frame,point,x,y (any order, extra columns ignored)"
        )
    repeated = [column for column in CSV_COLUMNS if names.count(column) > 1]
    if repeated:
        raise MeasurementError(
            f"the CSV header of {source_name} names column(s) {', '.join(repeated)} twice; "
            "name each of frame, point, x, y once"
        )
    return [names.index(column) for column in CSV_COLUMNS]


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


def read_csv(
    handle: IO[bytes],
    source_name: str,
    max_frames: int | None,
    max_points: int | None,
    admit: Admit | None = None,
    short_tracks: ShortTracks = "refuse",
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
        refuse_oversized(source_name, origin, n_frames, n_points, max_frames, max_points)
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
    if short_tracks == "drop":
        return Measurements.of_solvable_points(W)
    if n_frames >= 2 and n_points >= 3:  # else Measurements names the size problem
        check_observation_counts(
            np.bincount(linear % n_points, minlength=n_points),
            np.bincount(linear // n_points, minlength=n_frames),
        )
    return Measurements(W=W)
