"""Reading videos, image folders and masks for tracking, with size limits checked first.

A source is a video file (mp4, webm, avi, or any container OpenCV's FFmpeg backend decodes)
or a folder of PNG or JPEG images (one frame per file, in file-name order: number them with
leading zeros). Frames come out as RGB uint8 arrays (H, W, 3).

Everything that can be known before decoding is checked before decoding: the file size, the
resolution (from the container's header, or from each image's header), the number of frames
and the duration the container declares. The frame count is checked again while decoding,
since a container may declare fewer frames than it holds. Every failure is a
:class:`moju_core.errors.VideoError` (a :class:`~moju_core.errors.VideoTooLarge` for a limit)
whose message names the file, what is wrong and how to fix it.

OpenCV (``opencv-python-headless``, the ``video`` extra) is imported when a source is opened.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from moju_core.errors import VideoError, VideoTooLarge
from moju_core.file_types import JPEG_MAGIC, PNG_MAGIC

__all__ = [
    "DEFAULT_LIMITS",
    "IMAGE_EXTENSIONS",
    "VIDEO_EXTENSIONS",
    "VideoInfo",
    "VideoLimits",
    "open_video",
    "is_video_source",
    "read_mask",
]

#: File name endings taken for video files by :func:`is_video_source`.
VIDEO_EXTENSIONS = (".mp4", ".webm", ".avi")
#: Image files of an image-folder source.
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")
# JPEG start-of-frame markers (the ones that carry the image size).
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


@dataclass(frozen=True)
class VideoLimits:
    """What a source may hold; every limit is checked before the frames are decoded.

    Attributes
    ----------
    max_bytes : int
        Size of a video file, or of one image of a folder.
    max_width, max_height : int
        Frame size in pixels.
    max_frames : int
        Frames tracked (between ``start`` and ``end``).
    max_seconds : float
        Duration of the tracked frames, from the frame rate the container declares.
    max_points : int
        Tracks (grid points) of one run.
    """

    max_bytes: int = 2 * 1024**3
    max_width: int = 3840
    max_height: int = 2160
    max_frames: int = 1000
    max_seconds: float = 600.0
    max_points: int = 100_000


#: The limits used unless a caller gives others.
DEFAULT_LIMITS = VideoLimits()


@dataclass(frozen=True)
class VideoInfo:
    """What a source declares, read from headers only.

    Attributes
    ----------
    path : Path
        The video file or the image folder.
    width, height : int
        Frame size in pixels.
    n_frames : int or None
        Frames the source declares (None when the container does not say).
    fps : float or None
        Frame rate the container declares (None for an image folder or when unknown).
    images : tuple of Path
        The images of a folder source, in order (empty for a video file).
    limits : VideoLimits
        The limits the source was opened with (the folder's images are checked against them
        one by one as they are read).
    """

    path: Path
    width: int
    height: int
    n_frames: int | None
    fps: float | None
    images: tuple[Path, ...] = ()
    limits: VideoLimits = DEFAULT_LIMITS

    def clip(self, start: int, end: int | None) -> tuple[int, int | None]:
        """The frames ``start`` (inclusive) to ``end`` (exclusive) as far as they are known.

        Returns ``(start, end)`` with ``end`` clamped to the declared frame count (None when
        neither is known). Raises VideoError for a start beyond the declared frames.
        """
        if self.n_frames is not None:
            end = self.n_frames if end is None else min(end, self.n_frames)
            if start >= self.n_frames:
                raise VideoError(
                    f"{self.path.name} has {self.n_frames} frames; --start {start} is past "
                    f"the last one (frames are numbered from 0)"
                )
        return start, end

    def frames(self, start: int = 0, end: int | None = None) -> Iterator[np.ndarray]:
        """Decode frames ``start`` to ``end`` (exclusive; None: to the last) as RGB (H, W, 3)."""
        if self.images:
            yield from _read_images(self, start, end)
        else:
            yield from _decode_video(self, start, end)


def is_video_source(path: str | os.PathLike) -> bool:
    """True for a folder (of images) or a file named as a video (:data:`VIDEO_EXTENSIONS`)."""
    path = Path(path)
    return path.is_dir() or path.suffix.lower() in VIDEO_EXTENSIONS


def _name(path: Path) -> str:
    # Only the base name: an error message must not reveal a server's directory layout.
    return path.name or str(path)


def _check_frame_size(name: str, width: int, height: int, limits: VideoLimits) -> None:
    if width < 1 or height < 1:
        raise VideoError(f"{name} declares a frame size of {width} x {height} pixels")
    if width > limits.max_width or height > limits.max_height:
        raise VideoTooLarge(
            f"{name} is {width} x {height} pixels; the limit is {limits.max_width} x "
            f"{limits.max_height}. Scale the video down (e.g. ffmpeg -vf scale=1280:-2)"
        )


def check_clip(info: VideoInfo, start: int, end: int | None, limits: VideoLimits) -> None:
    """Refuse a clip longer than ``limits`` allow, from what the source declares."""
    if isinstance(start, bool) or not isinstance(start, int) or start < 0:
        raise ValueError(f"start must be an integer >= 0, got {start!r}")
    if end is not None and (isinstance(end, bool) or not isinstance(end, int) or end <= start):
        raise ValueError(f"end must be an integer > start ({start}) or None, got {end!r}")
    start, end = info.clip(start, end)
    if end is None:
        return
    count = end - start
    if count > limits.max_frames:
        raise VideoTooLarge(
            f"{_name(info.path)}: {count} frames to track, the limit is {limits.max_frames}; "
            "choose a shorter part with --start and --end"
        )
    if info.fps and count / info.fps > limits.max_seconds:
        raise VideoTooLarge(
            f"{_name(info.path)}: {count / info.fps:.0f} s to track at {info.fps:g} frames/s, "
            f"the limit is {limits.max_seconds:g} s; choose a shorter part with --start and --end"
        )


def open_video(path: str | os.PathLike, limits: VideoLimits = DEFAULT_LIMITS) -> VideoInfo:
    """Open a video file or an image folder and check its headers against ``limits``.

    Parameters
    ----------
    path : str or os.PathLike
        A video file or a folder of PNG or JPEG images.
    limits : VideoLimits
        Bytes and resolution are checked here; frames and duration by :func:`check_clip`.

    Returns
    -------
    info : VideoInfo

    Raises
    ------
    VideoError
        The source does not exist, is not a video or holds no images.
    VideoTooLarge
        A limit is exceeded.
    """
    path = Path(path)
    if path.is_dir():
        return _open_folder(path, limits)
    if not path.is_file():
        raise VideoError(f"{_name(path)} does not exist; give a video file or a folder of images")
    size = path.stat().st_size
    if size == 0:
        raise VideoError(f"{_name(path)} is empty (0 bytes)")
    if size > limits.max_bytes:
        raise VideoTooLarge(
            f"{_name(path)} is {size / 1024**2:.0f} MiB; the limit is "
            f"{limits.max_bytes / 1024**2:.0f} MiB. Cut or re-encode the video"
        )
    return _open_file(path, limits)


def _open_file(path: Path, limits: VideoLimits) -> VideoInfo:
    import cv2

    # FFmpeg only: other backends read e.g. "%d" patterns in a name as image sequences.
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    try:
        if not capture.isOpened():
            raise VideoError(
                f"{_name(path)} could not be opened as a video; give an mp4, webm or avi file "
                "(or a folder of PNG/JPEG images) and check that the file is complete"
            )
        width = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = float(capture.get(cv2.CAP_PROP_FPS))
    finally:
        capture.release()
    _check_frame_size(_name(path), width, height, limits)
    return VideoInfo(
        path=path,
        width=width,
        height=height,
        n_frames=count if count > 0 else None,
        fps=fps if np.isfinite(fps) and fps > 0 else None,
        limits=limits,
    )


def _decode_video(info: VideoInfo, start: int, end: int | None) -> Iterator[np.ndarray]:
    import cv2

    capture = cv2.VideoCapture(str(info.path), cv2.CAP_FFMPEG)
    try:
        index = 0
        while end is None or index < end:
            ok, frame = capture.read()
            if not ok:
                break
            if frame.shape != (info.height, info.width, 3):
                raise VideoError(
                    f"{_name(info.path)}: frame {index} is {frame.shape[1]} x {frame.shape[0]}, "
                    f"the video declares {info.width} x {info.height}"
                )
            if index >= start:
                yield cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
            index += 1
    finally:
        capture.release()
    _check_complete(info, index, end)


def _check_complete(info: VideoInfo, decoded: int, end: int | None) -> None:
    """Refuse a video that ends well before the frame count its header declares.

    A cut-off avi or webm still opens and decodes up to the cut; a container's count can be
    an estimate (from the duration), so a shortfall of one frame or 2 % is let through.
    """
    if info.n_frames is None:
        return
    wanted = info.n_frames if end is None else min(end, info.n_frames)
    shortfall = wanted - decoded
    if shortfall > max(1, 0.02 * wanted):
        raise VideoError(
            f"{_name(info.path)} declares {info.n_frames} frames but ends after {decoded}; "
            "the file looks truncated (re-copy or re-encode it)"
        )


# --- image folders -------------------------------------------------------------------------


def _open_folder(path: Path, limits: VideoLimits) -> VideoInfo:
    images = tuple(
        sorted(
            child
            for child in path.iterdir()
            if child.suffix.lower() in IMAGE_EXTENSIONS and child.is_file()
        )
    )
    if not images:
        raise VideoError(
            f"folder {_name(path)} holds no {'/'.join(IMAGE_EXTENSIONS)} images; put one image "
            "per frame there, named in frame order (frame_00000.png, frame_00001.png, ...)"
        )
    width, height = image_size(images[0], limits)
    return VideoInfo(
        path, width, height, n_frames=len(images), fps=None, images=images, limits=limits
    )


def _read_images(info: VideoInfo, start: int, end: int | None) -> Iterator[np.ndarray]:
    import cv2

    for image in info.images[start:end]:
        # Headers first: an image of another size must not be decoded at all.
        size = _header_size(image, info.limits.max_bytes)
        if size != (info.width, info.height):
            raise VideoError(
                f"{_name(image)} is {size[0]} x {size[1]} pixels, the first image of the folder "
                f"is {info.width} x {info.height}; every frame must have the same size"
            )
        frame = cv2.imread(str(image), cv2.IMREAD_COLOR)
        if frame is None:
            raise VideoError(f"{_name(image)} could not be decoded as an image")
        yield cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)


def image_size(path: Path, limits: VideoLimits) -> tuple[int, int]:
    """(width, height) of a PNG or JPEG file from its header, checked against ``limits``."""
    width, height = _header_size(path, limits.max_bytes)
    _check_frame_size(_name(path), width, height, limits)
    return width, height


def _header_size(path: Path, max_bytes: int) -> tuple[int, int]:
    """(width, height) a PNG or JPEG header declares; nothing else of the file is read."""
    size = path.stat().st_size
    if size > max_bytes:
        raise VideoTooLarge(
            f"{_name(path)} is {size / 1024**2:.0f} MiB; the limit per image is "
            f"{max_bytes / 1024**2:.0f} MiB"
        )
    with open(path, "rb") as handle:
        head = handle.read(24)
        if head.startswith(PNG_MAGIC) and head[12:16] == b"IHDR":
            return struct.unpack(">II", head[16:24])
        if head.startswith(JPEG_MAGIC):
            handle.seek(2)
            return _jpeg_size(handle, path)
    raise VideoError(f"{_name(path)} is not a PNG or JPEG image")


def _jpeg_size(handle, path: Path) -> tuple[int, int]:
    """Width and height from the first start-of-frame segment of a JPEG stream."""
    while True:
        marker = handle.read(2)
        if len(marker) < 2 or marker[0] != 0xFF:
            raise VideoError(f"{_name(path)}: no JPEG frame header found; the file is damaged")
        if marker[1] in (0xD8, 0x01) or 0xD0 <= marker[1] <= 0xD7:
            continue  # markers without a length
        length_bytes = handle.read(2)
        if len(length_bytes) < 2:
            raise VideoError(f"{_name(path)} is truncated")
        (length,) = struct.unpack(">H", length_bytes)
        if marker[1] in _JPEG_SOF:
            header = handle.read(5)
            if len(header) < 5:
                raise VideoError(f"{_name(path)} is truncated")
            height, width = struct.unpack(">HH", header[1:5])
            return width, height
        if length < 2:
            raise VideoError(f"{_name(path)}: damaged JPEG segment")
        handle.seek(length - 2, os.SEEK_CUR)


# --- masks ---------------------------------------------------------------------------------


def read_mask(path: str | os.PathLike, frame_size: tuple[int, int]) -> np.ndarray:
    """Read an object mask: a PNG of the frame's size whose non-zero pixels mark the object.

    Parameters
    ----------
    path : str or os.PathLike
        PNG file (grey, RGB or RGBA; with an alpha channel the alpha marks the object).
    frame_size : (int, int)
        (width, height) of the video's frames.

    Returns
    -------
    mask : ndarray of shape (H, W), bool
    """
    import cv2

    path = Path(path)
    if not path.is_file():
        raise VideoError(f"mask {_name(path)} does not exist")
    width, height = frame_size
    with open(path, "rb") as handle:
        if not handle.read(8).startswith(PNG_MAGIC):
            raise VideoError(f"mask {_name(path)} is not a PNG image")
    size = _header_size(path, DEFAULT_LIMITS.max_bytes)
    if size != (width, height):
        raise VideoError(
            f"mask {_name(path)} is {size[0]} x {size[1]} pixels, the video's frames are "
            f"{width} x {height}; draw the mask on the first frame at its size"
        )
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise VideoError(f"mask {_name(path)} could not be decoded as a PNG image")
    if image.ndim == 3:
        image = image[:, :, 3] if image.shape[2] == 4 else image.max(axis=2)
    mask = image > 0
    if not mask.any():
        raise VideoError(f"mask {_name(path)} marks no pixel; non-zero pixels mark the object")
    return mask
