"""Video uploads of ``POST /v1/jobs``: staged, checked against the limits, summarised.

A video (mp4, webm or avi, recognised by its first bytes) comes in the ``file`` part, with an
optional ``mask`` part (PNG, the first frame's size, non-zero pixels marking the object). The
file is copied to a private temporary directory (OpenCV reads files, not streams) and checked
there before a job exists:

* its size against ``MOJU_MAX_VIDEO_BYTES``, before it is copied;
* resolution, frames and duration from the container's headers against
  ``MOJU_MAX_VIDEO_WIDTH`` / ``_HEIGHT``, ``MOJU_MAX_VIDEO_FRAMES`` and
  ``MOJU_MAX_VIDEO_SECONDS`` (:class:`moju_core.footage.video.VideoLimits`; 413 naming the limit);
* the first two frames are decoded (a file that is no video, or holds one frame, is 422) and
  the first one is kept as PNG, for the web page;
* the mask's size against the frames', and its grid points against ``MOJU_MAX_POINTS``;
* the camera: the form's ``focal`` (principal point at the image centre) or ``intrinsics``,
  else the default camera of the frame size (:mod:`service.camera_fields`).

The tracking itself runs in the worker (:mod:`worker.jobs`); a video that turns out to be
truncated further on fails the job there with the tracker's message.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from starlette.datastructures import UploadFile

from moju_core import file_types
from moju_core.errors import VideoError, VideoTooLarge
from moju_core.feasibility import describe_bytes
from moju_core.footage.tracking import DEFAULT_STEP, count_grid_points
from moju_core.footage.video import VideoInfo, check_clip, open_video, read_mask
from service.camera_fields import CameraRequest, video_camera
from service.schemas import InputSummary, VideoSummary
from service.settings import Settings

#: Share of the frame above which a mask is taken for a photo rather than a mask (an RGB
#: frame sent as the mask is non-zero nearly everywhere).
MAX_MASK_COVERAGE = 0.98
#: Largest mask PNG read (a 1920 x 1080 RGBA PNG without compression is about 8 MiB).
MAX_MASK_BYTES = 16 * 2**20
_COPY_CHUNK = 2**20
_CLI_ADVICE = "choose a shorter part with --start and --end"
#: The settings behind :attr:`service.settings.Settings.video_limits`, named in a refusal.
LIMIT_SETTINGS = (
    "this server's limits: MOJU_MAX_VIDEO_WIDTH x MOJU_MAX_VIDEO_HEIGHT, "
    "MOJU_MAX_VIDEO_FRAMES, MOJU_MAX_VIDEO_SECONDS"
)


@dataclass
class StagedVideo:
    """An uploaded video, its mask and its first frame in a temporary directory.

    :meth:`close` removes the directory (the files are moved out when the job is stored).
    """

    directory: Path
    video: Path
    mask: Path | None
    first_frame: Path
    summary: InputSummary = field(repr=False)

    def close(self) -> None:
        shutil.rmtree(self.directory, ignore_errors=True)


def video_extension(upload: UploadFile) -> str | None:
    """``.mp4``, ``.webm`` or ``.avi`` when the upload starts like one, else None."""
    upload.file.seek(0)
    head = upload.file.read(file_types.HEAD_BYTES)
    upload.file.seek(0)
    return file_types.video_extension(head)


def _copy(source: UploadFile, target: Path, limit: int, what: str, setting: str) -> int:
    """Copy an upload to ``target``, refusing more than ``limit`` bytes (413)."""
    size = source.size
    if size is not None and size > limit:
        raise VideoTooLarge(_too_big(what, size, limit, setting))
    source.file.seek(0)
    copied = 0
    with open(target, "wb") as handle:
        while chunk := source.file.read(_COPY_CHUNK):
            copied += len(chunk)
            if copied > limit:
                raise VideoTooLarge(_too_big(what, copied, limit, setting))
            handle.write(chunk)
    return copied


def _too_big(what: str, size: int, limit: int, setting: str) -> str:
    return (
        f"the {what} is {describe_bytes(size)} ({size} bytes); this server accepts at most "
        f"{describe_bytes(limit)} ({limit} bytes, {setting}). Cut or re-encode it"
    )


def _first_frames(info: VideoInfo) -> np.ndarray:
    """Decode the first two frames; return the first. One frame only is refused (422)."""
    frames = info.frames(0, 2)
    try:
        first = next(frames, None)
        second = next(frames, None)
    finally:
        frames.close()
    if first is None:
        raise VideoError(f"{info.path.name}: no frame could be decoded; is the file complete?")
    if second is None:
        raise VideoError("the video holds one frame; tracking needs at least two")
    return first


def _count_frames(info: VideoInfo, limit: int) -> int:
    """Frames of a video whose container does not declare them, decoding at most limit + 1."""
    count = 0
    for _ in info.frames(0, limit + 1):
        count += 1
    if count > limit:
        raise VideoTooLarge(
            f"the video holds more than {limit} frames, the limit (MOJU_MAX_VIDEO_FRAMES); cut "
            "it shorter"
        )
    return count


def _write_png(path: Path, frame: np.ndarray) -> None:
    import cv2

    if not cv2.imwrite(str(path), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)):
        raise OSError(f"OpenCV could not write {path.name}")


def _check_coverage(mask: np.ndarray) -> None:
    """Refuse a mask that marks (nearly) the whole frame: most likely a photo of the frame."""
    coverage = float(mask.mean())
    if coverage > MAX_MASK_COVERAGE:
        raise VideoError(
            f"the mask marks {coverage * 100:.0f} % of the frame, so it looks like a picture "
            "of the frame rather than a mask: paint the object white (non-zero) and everything "
            "else black (0), or send no mask to track the textured part of the whole frame"
        )


def _check_points(n_points: int, has_mask: bool, settings: Settings) -> None:
    if n_points < 3:
        raise VideoError(
            f"the mask covers {n_points} grid point(s) at a step of {DEFAULT_STEP} pixels; "
            "a reconstruction needs at least 3: draw a larger mask"
        )
    if has_mask and n_points > settings.max_points:
        raise VideoTooLarge(
            f"the mask covers {n_points} grid points at a step of {DEFAULT_STEP} pixels; the "
            f"limit is {settings.max_points} tracks (MOJU_MAX_POINTS). Draw a smaller mask or "
            "scale the video down"
        )


def stage_video(
    upload: UploadFile,
    mask: UploadFile | None,
    extension: str,
    filename: str | None,
    settings: Settings,
    camera: CameraRequest | None = None,
) -> StagedVideo:
    """Copy and check an uploaded video (blocking: run in a worker thread); ``camera`` is the
    form's (None: the default camera of the frame size).

    Raises VideoTooLarge (413) for a limit and VideoError (422) for anything unusable;
    nothing is left behind then.
    """
    directory = Path(tempfile.mkdtemp(prefix="moju-video-"))
    try:
        return _stage(directory, upload, mask, extension, filename, settings, camera)
    except VideoTooLarge as exc:
        shutil.rmtree(directory, ignore_errors=True)
        # The tracker's advice names moju track's options, which an upload does not have.
        message = str(exc).replace(_CLI_ADVICE, "cut the video shorter")
        if "MOJU_" not in message:  # the tracker's limits, as this server sets them
            message += f" ({LIMIT_SETTINGS})"
        raise VideoTooLarge(message) from None
    except BaseException:
        shutil.rmtree(directory, ignore_errors=True)
        raise


def _stage(
    directory: Path,
    upload: UploadFile,
    mask: UploadFile | None,
    extension: str,
    filename: str | None,
    settings: Settings,
    camera: CameraRequest | None,
) -> StagedVideo:
    limits = settings.video_limits
    video = directory / f"video{extension}"
    size = _copy(upload, video, limits.max_bytes, "video", "MOJU_MAX_VIDEO_BYTES")
    info = open_video(video, limits)  # size and resolution
    check_clip(info, 0, None, limits)  # declared frames and duration
    first = _first_frames(info)
    n_frames = info.n_frames
    if n_frames is None:
        n_frames = _count_frames(info, limits.max_frames)
    mask_path = None
    if mask is not None:
        mask_path = directory / "mask.png"
        _copy(mask, mask_path, MAX_MASK_BYTES, "mask", "a PNG of the first frame's size")
        object_mask = read_mask(mask_path, (info.width, info.height))
        _check_coverage(object_mask)
    else:
        object_mask = np.ones((info.height, info.width), dtype=bool)
    n_points = count_grid_points(object_mask, DEFAULT_STEP)
    _check_points(n_points, mask is not None, settings)
    first_frame = directory / "first_frame.png"
    _write_png(first_frame, first)
    summary = InputSummary(
        frames=n_frames,
        points=min(n_points, settings.max_points),
        format="video",
        filename=filename,
        size_bytes=size,
        has_rotations=False,
        has_ground_truth=False,
        has_faces=False,
        has_colors=True,
        video=VideoSummary(
            width=info.width,
            height=info.height,
            fps=info.fps,
            has_mask=mask is not None,
            step=DEFAULT_STEP,
        ),
        camera=video_camera(camera, (info.width, info.height)),
    )
    return StagedVideo(directory, video, mask_path, first_frame, summary)
