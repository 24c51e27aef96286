"""Where job files live: the ``Storage`` protocol and its local-directory implementation.

Layout of :class:`LocalStorage` (the directory is the volume shared by the API and workers)::

    <data_dir>/jobs/<uuid>/input.npz     normalised input, as the API validated it (with its
                                         visibility when points are missing)
    <data_dir>/jobs/<uuid>/result.h5     the worker's result (moju_core.io.write_result)
    <data_dir>/jobs/<uuid>/result.npz    npz copy, made on the first npz download
    <data_dir>/jobs/<uuid>/metrics.json  accuracy against the ground truth, made on demand

A video job holds the upload instead of ``input.npz``, and the worker adds the tracks::

    <data_dir>/jobs/<uuid>/video.mp4       the uploaded video (.mp4, .webm or .avi, by content)
    <data_dir>/jobs/<uuid>/mask.png        the uploaded mask, when there is one
    <data_dir>/jobs/<uuid>/first_frame.png the first frame, decoded by the API at upload
    <data_dir>/jobs/<uuid>/tracks.npz      the tracker's output (footage.tracking.write_tracks)
    <data_dir>/jobs/<uuid>/input.npz       the tracks as solver input, written by the worker

Paths are built only from :class:`uuid.UUID` objects and fixed file names: no string a user
sent ever becomes part of a path. Every file is written under a temporary name and renamed
into place (``moju_core.io.atomic_output``), so a reader never sees half a file.

The API alone creates a job's directory; the worker never does. A worker that finishes after
the job was deleted therefore fails to write into the missing directory instead of
resurrecting it.
"""

from __future__ import annotations

import contextlib
import json
import shutil
from collections.abc import Iterator, Mapping
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any, Literal, Protocol
from uuid import UUID

import h5py
import numpy as np

from moju_core.footage.tracking import Tracks, write_tracks
from moju_core.footage.video import VIDEO_EXTENSIONS
from moju_core.io import (
    Measurements,
    atomic_output,
    read_measurements,
    read_result,
    write_measurements,
    write_result,
)
from moju_core.result import Result

ResultFormat = Literal["h5", "npz"]

INPUT_NAME = "input.npz"
RESULT_NAMES: dict[str, str] = {"h5": "result.h5", "npz": "result.npz"}
METRICS_NAME = "metrics.json"
MASK_NAME = "mask.png"
FIRST_FRAME_NAME = "first_frame.png"
TRACKS_NAME = "tracks.npz"
#: Names the uploaded video may be stored under (its extension follows its content).
VIDEO_NAMES = tuple(f"video{extension}" for extension in VIDEO_EXTENSIONS)


class JobFilesMissing(FileNotFoundError):
    """The job's directory does not exist (never created, or deleted)."""

    def __init__(self, job_id: UUID) -> None:
        super().__init__(f"no stored files for job {job_id}")
        self.job_id = job_id


class FrameReader:
    """Random access to the per-frame shapes of a stored result."""

    def __init__(self, shapes: h5py.Dataset) -> None:
        self._shapes = shapes

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self._shapes.shape[0])

    @property
    def n_points(self) -> int:
        """Number of points P."""
        return int(self._shapes.shape[1])

    def frame(self, index: int) -> np.ndarray:
        """Shape of frame ``index``, array of shape (P, 3)."""
        return np.asarray(self._shapes[index])


class Storage(Protocol):
    """Files of each job: input, result and derived downloads."""

    def create(self, job_id: UUID) -> None:
        """Make room for a new job (the only call that creates a job's area)."""

    def write_input(self, job_id: UUID, measurements: Measurements) -> None:
        """Store the validated input of a job."""

    def move_input(self, job_id: UUID, staged: Path) -> None:
        """Move an input already validated and written elsewhere (``input.npz`` layout) in."""

    def read_input(self, job_id: UUID) -> Measurements:
        """Read a job's input back."""

    def write_result(
        self, job_id: UUID, result: Result, metadata: Mapping[str, Any] | None = None
    ) -> None:
        """Store a job's result atomically."""

    def write_video(self, job_id: UUID, video: Path, mask: Path | None, first_frame: Path) -> None:
        """Move an uploaded video (and its mask and first frame) into the job's area."""

    def video_files(self, job_id: UUID) -> tuple[Path, Path | None]:
        """The stored video and its mask (or None) of a video job."""

    def write_tracks(self, job_id: UUID, tracks: Tracks) -> None:
        """Store a video job's tracks atomically."""

    def tracks_file(self, job_id: UUID) -> Path:
        """The stored tracks of a video job (JobFilesMissing when there are none)."""

    def first_frame_file(self, job_id: UUID) -> Path:
        """The first frame of a video job as PNG (JobFilesMissing when there is none)."""

    def has_result(self, job_id: UUID) -> bool:
        """True when the job's result is stored."""

    def read_result(self, job_id: UUID) -> Result:
        """Read a job's result."""

    def result_file(self, job_id: UUID, file_format: ResultFormat) -> Path:
        """A local file holding the result in ``file_format``, for downloads."""

    def result_frames(self, job_id: UUID) -> AbstractContextManager[FrameReader]:
        """Open the result for reading one frame's shape at a time."""

    def mesh_attributes(self, job_id: UUID) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Triangles (M, 3) and colours (P, 3|4) uploaded with the input, each or None."""

    def read_metrics(self, job_id: UUID) -> dict[str, float] | None:
        """Cached accuracy figures, or None when not computed yet."""

    def write_metrics(self, job_id: UUID, metrics: Mapping[str, float]) -> None:
        """Cache accuracy figures."""

    def delete(self, job_id: UUID) -> None:
        """Remove every file of a job (no error when there is none)."""

    def discard_outputs(self, job_id: UUID) -> list[str]:
        """Remove what running a job produced (result, caches, unfinished temporary files),
        keeping its input; return the names removed."""

    def stored_jobs(self) -> Iterator[tuple[UUID, float]]:
        """Every job that has files, with the time its area was last modified (epoch s)."""


class LocalStorage:
    """:class:`Storage` in a local (or network-mounted) directory."""

    def __init__(self, data_dir: Path | str) -> None:
        self.root = Path(data_dir).resolve() / "jobs"
        self.root.mkdir(parents=True, exist_ok=True)

    def _directory(self, job_id: UUID) -> Path:
        # str(UUID) is 36 hex digits and dashes: it cannot climb out of the root.
        if not isinstance(job_id, UUID):
            raise TypeError(f"job ids are UUID objects, got {type(job_id).__name__}")
        return self.root / str(job_id)

    def _existing_directory(self, job_id: UUID) -> Path:
        directory = self._directory(job_id)
        if not directory.is_dir():
            raise JobFilesMissing(job_id)
        return directory

    def create(self, job_id: UUID) -> None:
        """Create the job's directory; fails if it already exists (ids are never reused)."""
        self._directory(job_id).mkdir()

    def write_input(self, job_id: UUID, measurements: Measurements) -> None:
        """Store the normalised input as ``input.npz`` (compressed, atomic)."""
        write_measurements(self._existing_directory(job_id) / INPUT_NAME, measurements)

    def move_input(self, job_id: UUID, staged: Path) -> None:
        """Move a staged ``input.npz`` (checked and written by the upload check) in."""
        with atomic_output(self._existing_directory(job_id) / INPUT_NAME) as temporary:
            shutil.move(staged, temporary)

    def read_input(self, job_id: UUID) -> Measurements:
        """Read ``input.npz``; raises :class:`JobFilesMissing` when the job was deleted."""
        path = self._existing_directory(job_id) / INPUT_NAME
        if not path.is_file():
            raise JobFilesMissing(job_id)
        return read_measurements(path, format="npz")

    def write_result(
        self, job_id: UUID, result: Result, metadata: Mapping[str, Any] | None = None
    ) -> None:
        """Store ``result.h5`` (temporary name, then rename: see moju_core.io.write_result)."""
        write_result(
            self._existing_directory(job_id) / RESULT_NAMES["h5"], result, metadata=metadata
        )

    def write_video(self, job_id: UUID, video: Path, mask: Path | None, first_frame: Path) -> None:
        """Move the staged files in as ``video.<ext>``, ``mask.png`` and ``first_frame.png``."""
        directory = self._existing_directory(job_id)
        name = f"video{video.suffix.lower()}"
        if name not in VIDEO_NAMES:
            raise ValueError(f"a stored video is one of {', '.join(VIDEO_NAMES)}, not {name}")
        moves = [(first_frame, FIRST_FRAME_NAME), (video, name)]
        if mask is not None:
            moves.insert(0, (mask, MASK_NAME))
        for source, target in moves:  # the video last: its presence marks a complete upload
            with atomic_output(directory / target) as temporary:
                shutil.move(source, temporary)

    def video_files(self, job_id: UUID) -> tuple[Path, Path | None]:
        """``video.<ext>`` and ``mask.png`` (None when no mask was uploaded)."""
        directory = self._existing_directory(job_id)
        for name in VIDEO_NAMES:
            if (directory / name).is_file():
                mask = directory / MASK_NAME
                return directory / name, mask if mask.is_file() else None
        raise JobFilesMissing(job_id)

    def write_tracks(self, job_id: UUID, tracks: Tracks) -> None:
        """Store ``tracks.npz`` (temporary name, then rename)."""
        write_tracks(self._existing_directory(job_id) / TRACKS_NAME, tracks)

    def tracks_file(self, job_id: UUID) -> Path:
        """Path of ``tracks.npz``."""
        path = self._directory(job_id) / TRACKS_NAME
        if not path.is_file():
            raise JobFilesMissing(job_id)
        return path

    def first_frame_file(self, job_id: UUID) -> Path:
        """Path of ``first_frame.png``."""
        path = self._directory(job_id) / FIRST_FRAME_NAME
        if not path.is_file():
            raise JobFilesMissing(job_id)
        return path

    def has_result(self, job_id: UUID) -> bool:
        """True when ``result.h5`` exists."""
        return (self._directory(job_id) / RESULT_NAMES["h5"]).is_file()

    def read_result(self, job_id: UUID) -> Result:
        """Read ``result.h5``."""
        path = self._directory(job_id) / RESULT_NAMES["h5"]
        if not path.is_file():
            raise JobFilesMissing(job_id)
        return read_result(path)

    def result_file(self, job_id: UUID, file_format: ResultFormat) -> Path:
        """Path of the result in ``file_format``; the npz copy is made once, on first use."""
        h5_path = self._directory(job_id) / RESULT_NAMES["h5"]
        if not h5_path.is_file():
            raise JobFilesMissing(job_id)
        if file_format == "h5":
            return h5_path
        npz_path = h5_path.with_name(RESULT_NAMES["npz"])
        if not npz_path.is_file():
            # Two concurrent first downloads both convert; each rename is atomic, so either
            # copy wins and both are identical.
            write_result(npz_path, read_result(h5_path))  # with the stored metadata
        return npz_path

    @contextlib.contextmanager
    def result_frames(self, job_id: UUID) -> Iterator[FrameReader]:
        """Read frames from ``result.h5`` one at a time (HDF5 reads only that slice)."""
        path = self._directory(job_id) / RESULT_NAMES["h5"]
        if not path.is_file():
            raise JobFilesMissing(job_id)
        with h5py.File(path, "r") as h5:
            # "shapes" (F, P, 3) at the root is the documented result layout of moju_core.io.
            yield FrameReader(h5["shapes"])

    def mesh_attributes(self, job_id: UUID) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``faces`` and ``colors`` of ``input.npz`` (written by us, so read directly)."""
        path = self._existing_directory(job_id) / INPUT_NAME
        with np.load(path, allow_pickle=False) as npz:
            faces = npz["faces"] if "faces" in npz.files else None
            colors = npz["colors"] if "colors" in npz.files else None
        return faces, colors

    def read_metrics(self, job_id: UUID) -> dict[str, float] | None:
        """Cached ``metrics.json``, or None."""
        path = self._directory(job_id) / METRICS_NAME
        if not path.is_file():
            return None
        return json.loads(path.read_text())

    def write_metrics(self, job_id: UUID, metrics: Mapping[str, float]) -> None:
        """Cache ``metrics.json`` atomically."""
        path = self._existing_directory(job_id) / METRICS_NAME
        with atomic_output(path) as temporary:
            temporary.write_text(json.dumps(dict(metrics)))

    def delete(self, job_id: UUID) -> None:
        """Remove the job's directory and everything in it."""
        shutil.rmtree(self._directory(job_id), ignore_errors=True)

    def discard_outputs(self, job_id: UUID) -> list[str]:
        """Remove the result, its cached conversions and every unfinished temporary file.

        For a job whose worker was lost: what the lost attempt wrote (a temporary file it
        was writing when it died, or a result it renamed into place just before) must not
        outlive it. Only the upload stays: ``input.npz``, or for a video job the video, its
        mask and first frame (its ``tracks.npz`` and ``input.npz`` are the worker's).
        """
        directory = self._directory(job_id)
        if not directory.is_dir():
            return []
        outputs = {*RESULT_NAMES.values(), METRICS_NAME}
        if any((directory / name).is_file() for name in VIDEO_NAMES):
            outputs |= {TRACKS_NAME, INPUT_NAME}
        removed = []
        for entry in directory.iterdir():
            name = entry.name
            # atomic_output's temporary files are ".<final name>.<hex>.tmp".
            temporary = name.startswith(".") and name.endswith(".tmp")
            if (name in outputs or temporary) and entry.is_file():
                entry.unlink(missing_ok=True)
                removed.append(name)
        return sorted(removed)

    def stored_jobs(self) -> Iterator[tuple[UUID, float]]:
        """Job directories with their modification times; foreign entries are skipped."""
        for entry in self.root.iterdir():
            try:
                job_id = UUID(entry.name)
                modified = entry.stat().st_mtime
            except (ValueError, OSError):
                continue
            if entry.is_dir() and str(job_id) == entry.name:
                yield job_id, modified
