"""Dense 2D point tracks from a video, by chained optical flow with consistency checks.

The points are a grid (every ``step`` pixels) over the object in the first frame, given by a
mask or, without one, the textured part of the frame. Each is followed through the video:

1. **Chaining** (Sundaram, Brox and Keutzer, "Dense point trajectories by GPU-accelerated
   large displacement optical flow", ECCV 2010): dense flow between consecutive frames, forward
   ``w`` and backward ``w_hat``, with DIS (Kroeger, Timofte, Dai and Van Gool, "Fast optical flow
   using dense inverse search", ECCV 2016) or Farneback's polynomial expansion (Farneback, "Two-
   frame motion estimation based on polynomial expansion", SCIA 2003), both from OpenCV. A point
   at ``p`` moves to ``p + w(p)`` (flow sampled bilinearly).
2. **Consistency checks** (Sundaram et al.'s criteria): the track stops when
   ``|w + w_hat|^2 > 0.01 (|w|^2 + |w_hat|^2) + 0.5`` pixels^2, with ``w_hat`` sampled at the
   new position (a point that gets occluded has a backward flow that follows the occluder),
   or near a motion boundary, where ``|grad u|^2 + |grad v|^2 > 0.01 |w|^2 + 0.05`` (there the
   forward and backward flows can agree on the occluder's motion). The boundary constant is
   0.05 instead of the paper's 0.002: on the rendered test videos the smooth flow of a
   deforming, foreshortened surface exceeded 0.002 on a third to a half of the tracks, while
   an occluding edge exceeds 0.05 by far. A track that leaves the frame stops too. A stopped
   track is lost for good: NaN from then on.
3. **Re-anchoring** against drift: chaining adds the interpolation error of every step. Each
   frame is also matched directly to a keyframe (the first frame to begin with); where that
   long-range flow passes the same forward-backward check and agrees with the chained position
   within ``_ANCHOR_AGREEMENT`` pixels, the point takes the anchored position, so its error no
   longer grows with the number of frames. When fewer than ``_KEYFRAME_SUCCESS`` of the live
   tracks can be anchored (the view has changed too much), the current frame becomes the
   keyframe.

Positions are pixels of the video: x to the right, y down, the centre of the top-left pixel at
(0, 0) (not centred on the object). The result is a :class:`Tracks`; :func:`write_tracks`
stores it as an npz with ``W`` (NaN where lost), ``visibility``, ``colors`` and
``frame_size``.

OpenCV (``opencv-python-headless``, the ``video`` extra) is imported when tracking starts.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np

from moju_core.cameras.intrinsics import Intrinsics
from moju_core.errors import Cancelled, VideoError, VideoTooLarge
from moju_core.footage.video import DEFAULT_LIMITS, VideoLimits, check_clip, open_video, read_mask
from moju_core.io import Measurements, atomic_output
from moju_core.validation import MIN_POINTS_PER_FRAME, solvable_points

__all__ = [
    "DEFAULT_STEP",
    "Tracks",
    "count_grid_points",
    "TrackingProgress",
    "textured_region",
    "track_frames",
    "solvable_tracks",
    "track_video",
    "tracks_measurements",
    "write_tracks",
]

FlowMethod = Literal["dis", "farneback"]

#: Grid spacing in pixels unless told otherwise: 4 gives about 4,800 tracks on a 320 x 240
#: object filling the frame and 57,600 on a full 1280 x 720 frame.
DEFAULT_STEP = 4

# Sundaram et al.'s forward-backward tolerance: relative part and constant part (pixels^2).
_FB_RELATIVE, _FB_CONSTANT = 0.01, 0.8
# Sundaram et al.'s motion-boundary tolerance on |grad u|^2 + |grad v|^2: relative, constant.
_BOUNDARY_RELATIVE, _BOUNDARY_CONSTANT = 0.01, 0.05
# A direct match to the keyframe replaces the chained position when the two agree this well.
_ANCHOR_AGREEMENT = 1.5
# Points per row of the maps that sample a flow (remap takes fewer than 32767 a side).
_SAMPLE_ROW = 4096
# The flow gradient of the motion-boundary test: central differences this many pixels apart.
_GRADIENT_SPACING = 3.0
# Flows are computed on the box around the live tracks widened by this many pixels (the
# motion between the frames compared stays well within it; a track that leaves the box is
# lost). At 48 px the 640 x 480 paper's median error grew from 0.053 to 0.067 px (DIS's
# coarse levels see less context); at 96 px it was unchanged.
_REGION_MARGIN = 96
# The keyframe match runs every this many frames.
_ANCHOR_EVERY = 2
# Below this fraction of live tracks anchored to the keyframe, the current frame becomes it.
_KEYFRAME_SUCCESS = 0.8
# Textured region: local standard deviation of the grey levels (0..255) over a window.
_TEXTURE_WINDOW, _TEXTURE_MIN_STD = 7, 3.0


@dataclass(frozen=True)
class TrackingProgress:
    """Progress of a tracking run, given to the callback after every frame.

    Attributes
    ----------
    frame : int
        Frames tracked so far (1 after the first frame).
    n_frames : int or None
        Frames to track, when the source declares it.
    alive : int
        Tracks still followed.
    n_points : int
        Tracks started in the first frame.
    """

    frame: int
    n_frames: int | None
    alive: int
    n_points: int


@dataclass(frozen=True, eq=False)
class Tracks:
    """Dense 2D tracks of the points of a video's first frame.

    Attributes
    ----------
    W : ndarray of shape (2F, P), float64
        Rows ``2f`` and ``2f + 1`` are the x and y pixel positions in frame ``f`` (x right, y
        down, pixel centres at integers); NaN where the track is lost.
    visibility : ndarray of shape (F, P), bool
        True where the track has a position.
    colors : ndarray of shape (P, 3), uint8
        RGB of every point in the first frame.
    frame_size : (int, int)
        (width, height) of the frames in pixels.
    intrinsics : Intrinsics or None
        The camera matrix the user gave for the video (:mod:`moju_core.cameras.intrinsics`);
        None when none was given (readers then take the default camera of ``frame_size``).
    """

    W: np.ndarray
    visibility: np.ndarray
    colors: np.ndarray
    frame_size: tuple[int, int]
    intrinsics: Intrinsics | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.visibility.shape[0])

    @property
    def n_points(self) -> int:
        """Number of tracks P."""
        return int(self.visibility.shape[1])

    @property
    def fraction_kept(self) -> float:
        """Fraction of the track-frames (F x P) that have a position."""
        return float(self.visibility.mean()) if self.visibility.size else 0.0


def textured_region(frame: np.ndarray) -> np.ndarray:
    """Pixels with texture to track: grey-level standard deviation >= 3 (of 255) over every
    7 x 7 window that holds the pixel.

    Parameters
    ----------
    frame : ndarray of shape (H, W, 3), uint8
        RGB frame.

    Returns
    -------
    mask : ndarray of shape (H, W), bool
    """
    import cv2

    grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY).astype(np.float32)
    window = (_TEXTURE_WINDOW, _TEXTURE_WINDOW)
    mean = cv2.blur(grey, window)
    variance = np.maximum(cv2.blur(grey * grey, window) - mean * mean, 0.0)
    textured = (np.sqrt(variance) >= _TEXTURE_MIN_STD).astype(np.uint8)
    # A window that straddles an object's outline has a high deviation from the outline
    # alone; eroding by the window size keeps only the pixels of the textured area itself.
    return cv2.erode(textured, np.ones(window, dtype=np.uint8)).astype(bool)


def _grid(mask: np.ndarray, step: int) -> np.ndarray:
    """Grid points (P, 2) float64 (x, y) every ``step`` pixels, where ``mask`` is set."""
    height, width = mask.shape
    offset = step // 2
    ys, xs = np.meshgrid(
        np.arange(offset, height, step), np.arange(offset, width, step), indexing="ij"
    )
    keep = mask[ys, xs]
    return np.stack([xs[keep], ys[keep]], axis=1).astype(np.float64)


def count_grid_points(mask: np.ndarray, step: int = DEFAULT_STEP) -> int:
    """Number of tracks a run starts with: grid points every ``step`` pixels on ``mask``
    (H, W) bool."""
    return int(_grid(np.asarray(mask, dtype=bool), step).shape[0])


@dataclass(frozen=True)
class DISSettings:
    """Settings of one OpenCV DIS flow (see ``cv2.DISOpticalFlow``), starting from the
    medium preset.

    Attributes
    ----------
    finest_scale : int
        Finest pyramid level computed: 0 is the full resolution, 1 half (the preset's).
    patch_stride : int
        Pixels between the patches matched (the preset: 3).
    gradient_descent_iterations : int
        Iterations of each patch's inverse search (the preset: 25).
    variational_refinement_iterations : int
        Iterations of the variational refinement at every level (the preset: 5).
    """

    finest_scale: int = 1
    patch_stride: int = 3
    gradient_descent_iterations: int = 25
    variational_refinement_iterations: int = 5


#: OpenCV's medium preset as it is: the unit of the tracker's speed (benchmarks/tracking.py).
DIS_MEDIUM = DISSettings()
#: Forward flow between consecutive frames, the one the tracks follow: the full resolution
#: (the preset stops at half), with patches every 6 pixels instead of 3, 8 descent iterations
#: instead of 25 and no variational refinement, which costs about 0.7 of the preset (at full
#: resolution the whole preset costs 4 times as much) and was more accurate than the preset
#: on the rendered videos (median error per frame pair 0.024 px against 0.040 on the 640 x 480
#: paper, 0.052 against 0.11 on the 320 x 240 face).
CHAIN_DIS = DISSettings(
    finest_scale=0, patch_stride=6, gradient_descent_iterations=8,
    variational_refinement_iterations=0,
)  # fmt: skip
#: Backward flow between consecutive frames, for the forward-backward check: the same
#: settings. (Cheaper ones, at half resolution or with sparser patches, lost a small object
#: moving across a background: its flow is wrong there.)
CHECK_DIS = CHAIN_DIS
#: Flow from the keyframe, the anchor against drift: across many frames the surface has
#: deformed, and only the full resolution with variational refinement stays accurate (4
#: frames apart on the face: median 0.09 px against 0.26 for the preset at half resolution;
#: without refinement the 90th percentile grows to several pixels). Patches every 4 pixels and
#: 3 refinement iterations cost 2.6 times the preset, against 4 for the whole preset at full
#: resolution, for the same accuracy.
ANCHOR_DIS = DISSettings(finest_scale=0, patch_stride=4, variational_refinement_iterations=3)


class _Flow:
    """Dense optical flow between grey frames: (H, W, 2) float32 displacements in pixels."""

    def __init__(self, method: FlowMethod, settings: DISSettings = DIS_MEDIUM) -> None:
        import cv2

        self._cv2 = cv2
        self.method = method
        if method == "dis":
            self._dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
            self._dis.setFinestScale(settings.finest_scale)
            self._dis.setPatchStride(settings.patch_stride)
            self._dis.setGradientDescentIterations(settings.gradient_descent_iterations)
            self._dis.setVariationalRefinementIterations(settings.variational_refinement_iterations)
        elif method != "farneback":
            raise ValueError(f"method must be 'dis' or 'farneback', got {method!r}")

    def __call__(self, first: np.ndarray, second: np.ndarray) -> np.ndarray:
        if self.method == "dis":
            return self._dis.calc(first, second, None)
        return self._cv2.calcOpticalFlowFarneback(
            first, second, None, pyr_scale=0.5, levels=5, winsize=15, iterations=5,
            poly_n=7, poly_sigma=1.5, flags=0,
        )  # fmt: skip

    def sample(self, flow: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Bilinear samples of ``flow`` at ``points`` (n, 2) inside the frame, (n, 2)."""
        n = points.shape[0]
        if n == 0:
            return np.zeros((0, 2))
        # remap takes maps of fewer than 32767 rows and columns: the points are laid out as
        # rows of _SAMPLE_ROW (padded with the last point).
        rows = -(-n // _SAMPLE_ROW)
        columns = -(-n // rows)
        grid = np.empty((rows * columns, 2), dtype=np.float32)
        grid[:n] = points
        grid[n:] = points[-1]
        grid = grid.reshape(rows, columns, 2)
        sampled = self._cv2.remap(
            flow, grid[..., 0], grid[..., 1], self._cv2.INTER_LINEAR,
            borderMode=self._cv2.BORDER_REPLICATE,
        )  # fmt: skip
        return sampled.reshape(-1, 2)[:n].astype(np.float64)


def _consistent(forward: np.ndarray, backward: np.ndarray) -> np.ndarray:
    """(n,) bool: Sundaram et al.'s forward-backward check on sampled flows (n, 2)."""
    error = np.sum((forward + backward) ** 2, axis=1)
    scale = np.sum(forward**2, axis=1) + np.sum(backward**2, axis=1)
    return error <= _FB_RELATIVE * scale + _FB_CONSTANT


def _flow_gradient(flow: _Flow, field: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n,) ``|grad u|^2 + |grad v|^2`` of the flow ``field`` (H, W, 2) at ``points`` (n, 2),
    by central differences of bilinear samples one pixel apart (at the points only, not over
    the whole frame)."""
    h = _GRADIENT_SPACING
    offsets = np.array([[h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    n = points.shape[0]
    around = (points[None, :, :] + offsets[:, None, :]).reshape(-1, 2)
    samples = flow.sample(field, around).reshape(4, n, 2)
    d_x = (samples[0] - samples[1]) / (2 * h)
    d_y = (samples[2] - samples[3]) / (2 * h)
    return np.sum(d_x * d_x, axis=1) + np.sum(d_y * d_y, axis=1)


def _motion_boundary(gradient: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """(n,) bool: Sundaram et al.'s motion-boundary test on flow gradients (n,)."""
    return gradient > _BOUNDARY_RELATIVE * np.sum(forward**2, axis=1) + _BOUNDARY_CONSTANT


def _inside(points: np.ndarray, width: int, height: int) -> np.ndarray:
    """(n,) bool: positions within the frame (pixel centres from 0 to size - 1)."""
    return (
        (points[:, 0] >= 0)
        & (points[:, 0] <= width - 1)
        & (points[:, 1] >= 0)
        & (points[:, 1] <= height - 1)
    )


@dataclass(frozen=True)
class _Region:
    """A box of the frame, pixels ``x0 <= x < x1``, ``y0 <= y < y1``, in a frame of
    ``width`` x ``height``."""

    x0: int
    y0: int
    x1: int
    y1: int
    width: int
    height: int

    def of(self, image: np.ndarray) -> np.ndarray:
        """The box's part of ``image`` (H, W), contiguous (as DIS needs)."""
        return np.ascontiguousarray(image[self.y0 : self.y1, self.x0 : self.x1])

    def local(self, points: np.ndarray) -> np.ndarray:
        """Frame positions (n, 2) in the box's coordinates."""
        return points - np.array([self.x0, self.y0], dtype=np.float64)

    def holds(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: positions (n, 2) inside the frame and the box."""
        local = self.local(points)
        return _inside(points, self.width, self.height) & _inside(
            local, self.x1 - self.x0, self.y1 - self.y0
        )


class _Tracker:
    """State of a tracking run: live tracks, their positions, and the keyframe."""

    def __init__(self, first_grey: np.ndarray, points: np.ndarray, method: FlowMethod) -> None:
        # One flow object (and its buffers) per role, reused for every frame.
        self.chain = _Flow(method, CHAIN_DIS)
        self.check = _Flow(method, CHECK_DIS)
        self.anchor = _Flow(method, ANCHOR_DIS)
        self.height, self.width = first_grey.shape
        self.previous = first_grey
        self.positions = points.copy()  # (P, 2), NaN once lost
        self.alive = np.ones(points.shape[0], dtype=bool)
        self.key_grey, self.key_positions = first_grey, points.copy()
        self.key_index = self.index = 0

    def step(self, grey: np.ndarray) -> None:
        """Follow the live tracks into the next frame ``grey`` (H, W) uint8."""
        self.index += 1
        live = np.flatnonzero(self.alive)
        if live.size == 0:
            return  # every track is lost; nothing left to match
        moved, ok = self._follow(grey, self.positions[live])
        renew = False
        since_key = self.index - self.key_index
        if since_key > 1 and since_key % _ANCHOR_EVERY == 0:
            start = self.key_positions[live]
            region = self._region(start, moved[ok])
            forward = self.anchor(region.of(self.key_grey), region.of(grey))
            anchored = start + self.anchor.sample(forward, region.local(start))
            anchor_ok = ok & region.holds(anchored)
            anchor_ok &= np.linalg.norm(anchored - moved, axis=1) <= _ANCHOR_AGREEMENT
            moved[anchor_ok] = anchored[anchor_ok]
            renew = anchor_ok.sum() < _KEYFRAME_SUCCESS * ok.sum()
        self.positions[live] = np.where(ok[:, None], moved, np.nan)
        self.alive[live] = ok
        if renew:
            self.key_grey, self.key_positions = grey, self.positions.copy()
            self.key_index = self.index
        self.previous = grey

    def _follow(self, grey: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (n, 2) in ``grey`` of ``points`` (n, 2) of the previous frame, and (n,)
        whether they passed the frame, forward-backward and motion-boundary checks."""
        region = self._region(points)
        first, second = region.of(self.previous), region.of(grey)
        forward = self.chain(first, second)
        moved_by = self.chain.sample(forward, region.local(points))
        moved = points + moved_by
        ok = region.holds(moved)
        back = np.zeros_like(moved_by)
        back[ok] = self.check.sample(self.check(second, first), region.local(moved[ok]))
        ok &= _consistent(moved_by, back)
        gradient = _flow_gradient(self.chain, forward, region.local(points))
        ok &= ~_motion_boundary(gradient, moved_by)
        return moved, ok

    def _region(self, *points: np.ndarray) -> _Region:
        """The part of the frame the flows are computed on: the box around ``points`` (each
        (n, 2)) widened by :data:`_REGION_MARGIN`, within the frame."""
        every = np.concatenate(points)
        low = np.floor(every.min(axis=0)) - _REGION_MARGIN
        high = np.ceil(every.max(axis=0)) + _REGION_MARGIN + 1
        x0, y0 = (max(int(value), 0) for value in low)
        x1, y1 = min(int(high[0]), self.width), min(int(high[1]), self.height)
        return _Region(x0, y0, x1, y1, self.width, self.height)


def track_frames(
    frames: Iterable[np.ndarray],
    *,
    mask: np.ndarray | None = None,
    step: int = DEFAULT_STEP,
    method: FlowMethod = "dis",
    n_frames: int | None = None,
    max_points: int = DEFAULT_LIMITS.max_points,
    callback: Callable[[TrackingProgress], bool | None] | None = None,
) -> Tracks:
    """Track a grid of first-frame points through ``frames``.

    Parameters
    ----------
    frames : iterable of ndarray of shape (H, W, 3), uint8
        RGB frames, all of one size; at least two.
    mask : ndarray of shape (H, W), bool, optional
        The object in the first frame. Without one the textured region is tracked
        (:func:`textured_region`) and a warning says so.
    step : int, default DEFAULT_STEP
        Grid spacing in pixels.
    method : {"dis", "farneback"}, default "dis"
        OpenCV dense optical flow.
    n_frames : int, optional
        Number of frames, if known (for the progress reports only).
    max_points : int
        Refuse grids with more points than this (VideoTooLarge).
    callback : callable, optional
        Called with a :class:`TrackingProgress` after every frame; returning True cancels
        (raises :class:`moju_core.errors.Cancelled`).

    Returns
    -------
    tracks : Tracks
    """
    import cv2

    if isinstance(step, bool) or not isinstance(step, int) or step < 1:
        raise ValueError(f"step must be an integer >= 1 (pixels), got {step!r}")
    iterator: Iterator[np.ndarray] = iter(frames)
    first = next(iterator, None)
    if first is None:
        raise VideoError("the video holds no frames that could be decoded")
    first = _check_frame(first, None)
    height, width = first.shape[:2]
    if mask is None:
        mask = textured_region(first)
        warnings.warn(
            f"no mask given: tracking the textured region of the first frame "
            f"({mask.mean():.0%} of it); give a mask to track one object only",
            stacklevel=2,
        )
    elif mask.shape != (height, width):
        raise VideoError(
            f"the mask is {mask.shape[1]} x {mask.shape[0]} pixels, the frames are "
            f"{width} x {height}"
        )
    points = _grid(np.asarray(mask, dtype=bool), step)
    if points.shape[0] == 0:
        raise VideoError(
            f"no grid point falls on the object (mask of {int(mask.sum())} pixels, step "
            f"{step}); use a smaller step or a larger mask"
        )
    if points.shape[0] > max_points:
        raise VideoTooLarge(
            f"{points.shape[0]} tracks at step {step}; the limit is {max_points}. Use a larger "
            "--step or a smaller mask"
        )
    pixels = points.astype(np.int64)
    colors = np.ascontiguousarray(first[pixels[:, 1], pixels[:, 0]])
    tracker = _Tracker(cv2.cvtColor(first, cv2.COLOR_RGB2GRAY), points, method)
    history = [points.copy()]
    _report(callback, 1, n_frames, tracker)
    for frame in iterator:
        grey = cv2.cvtColor(_check_frame(frame, (height, width)), cv2.COLOR_RGB2GRAY)
        tracker.step(grey)
        history.append(tracker.positions.copy())
        _report(callback, len(history), n_frames, tracker)
    if len(history) < 2:
        raise VideoError("the video holds one frame; tracking needs at least two")
    positions = np.stack(history)  # (F, P, 2)
    W = positions.transpose(0, 2, 1).reshape(2 * positions.shape[0], -1)
    visibility = np.isfinite(positions[:, :, 0])
    return Tracks(W=W, visibility=visibility, colors=colors, frame_size=(width, height))


def _check_frame(frame: np.ndarray, size: tuple[int, int] | None) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(
            f"frames must be RGB uint8 arrays (H, W, 3), got {frame.dtype} {frame.shape}"
        )
    if size is not None and frame.shape[:2] != size:
        raise VideoError(
            f"a frame is {frame.shape[1]} x {frame.shape[0]} pixels, the first is "
            f"{size[1]} x {size[0]}; every frame must have the same size"
        )
    return frame


def _report(
    callback: Callable[[TrackingProgress], bool | None] | None,
    frame: int,
    n_frames: int | None,
    tracker: _Tracker,
) -> None:
    if callback is None:
        return
    progress = TrackingProgress(frame, n_frames, int(tracker.alive.sum()), tracker.alive.size)
    if callback(progress):
        raise Cancelled("tracking cancelled by the progress callback")


def track_video(
    source: str | os.PathLike,
    *,
    mask: str | os.PathLike | np.ndarray | None = None,
    step: int = DEFAULT_STEP,
    start: int = 0,
    end: int | None = None,
    method: FlowMethod = "dis",
    limits: VideoLimits = DEFAULT_LIMITS,
    callback: Callable[[TrackingProgress], bool | None] | None = None,
) -> Tracks:
    """Dense 2D tracks of the object in a video's first tracked frame.

    Parameters
    ----------
    source : str or os.PathLike
        A video file (mp4, webm, avi) or a folder of PNG/JPEG images, one per frame.
    mask : path, ndarray of shape (H, W) bool, or None
        The object in frame ``start``: a PNG whose non-zero pixels mark it, or a boolean
        array. Without one the textured region is tracked, with a warning.
    step : int, default DEFAULT_STEP
        Grid spacing in pixels.
    start, end : int
        Frames ``start`` (inclusive, from 0) to ``end`` (exclusive; None: to the last).
    method : {"dis", "farneback"}, default "dis"
        OpenCV dense optical flow.
    limits : VideoLimits
        Bytes, resolution, frames, duration and points a run may take; checked from the
        headers before decoding.
    callback : callable, optional
        Receives a :class:`TrackingProgress` after every frame; returning True cancels.

    Returns
    -------
    tracks : Tracks
        F = the frames tracked; P = the grid points on the object.

    Raises
    ------
    VideoError
        The source or the mask cannot be used; VideoTooLarge for a limit.
    """
    info = open_video(source, limits)
    check_clip(info, start, end, limits)
    if mask is not None and not isinstance(mask, np.ndarray):
        mask = read_mask(mask, (info.width, info.height))
    first, last = info.clip(start, end)
    n_frames = None if last is None else last - first
    frames = _bounded(info.frames(first, last), limits.max_frames, info.path.name)
    return track_frames(
        frames,
        mask=mask,
        step=step,
        method=method,
        n_frames=n_frames,
        max_points=limits.max_points,
        callback=callback,
    )


def _bounded(frames: Iterator[np.ndarray], max_frames: int, name: str) -> Iterator[np.ndarray]:
    """``frames``, refusing more than ``max_frames`` (a container may under-declare)."""
    for count, frame in enumerate(frames, start=1):
        if count > max_frames:
            raise VideoTooLarge(
                f"{name} holds more than {max_frames} frames to track, the limit; choose a "
                "shorter part with --start and --end"
            )
        yield frame


def write_tracks(path: str | os.PathLike, tracks: Tracks) -> None:
    """Write ``tracks`` to an npz: ``W`` (2F, P) float64 with NaN where lost, ``visibility``
    (F, P) bool, ``colors`` (P, 3) uint8, ``frame_size`` (2,) int64 = (width, height) and,
    when the tracks carry intrinsics other than the default, ``K`` (3, 3) float64 in pixels.

    The file is written under a temporary name and renamed, so no partial file is left.
    """
    arrays = {
        "W": tracks.W,
        "visibility": tracks.visibility,
        "colors": tracks.colors,
        "frame_size": np.asarray(tracks.frame_size, dtype=np.int64),
    }
    if tracks.intrinsics is not None and tracks.intrinsics.origin != "default":
        arrays["K"] = tracks.intrinsics.K
    with atomic_output(path) as temporary, open(temporary, "wb") as handle:
        np.savez_compressed(handle, **arrays)


def solvable_tracks(tracks: Tracks) -> Tracks:
    """The tracks the solver can use, in their original order: those with a position in at
    least :data:`moju_core.validation.MIN_FRAMES_PER_POINT` frames (a track lost right after
    the first frame gives no depth), chosen and announced by
    :func:`moju_core.validation.solvable_points` (a warning says how many are left out), the
    rule a tracks file read with ``short_tracks="drop"`` follows too.

    Raises VideoError when fewer than :data:`MIN_POINTS_PER_FRAME` tracks are left, in all or
    in some frame (frames are numbered from the first tracked one).
    """
    keep = solvable_points(tracks.W, tracks.visibility)
    if np.count_nonzero(keep) < MIN_POINTS_PER_FRAME:
        raise VideoError(
            f"only {int(np.count_nonzero(keep))} of {tracks.n_points} tracks were followed "
            f"beyond the first frame; a reconstruction needs at least {MIN_POINTS_PER_FRAME}. "
            "Check the mask, use a smaller step or a video with less motion between frames"
        )
    thin = np.flatnonzero(
        np.count_nonzero(tracks.visibility[:, keep], axis=1) < MIN_POINTS_PER_FRAME
    )
    if thin.size:
        raise VideoError(
            f"fewer than {MIN_POINTS_PER_FRAME} tracks are left from frame {thin[0]} on (of "
            f"{tracks.n_frames} tracked; the tracker lost the others), too few for a camera: "
            f"reconstruct the frames before it (moju: --end {thin[0]}), or use a video with "
            "less motion between frames"
        )
    if keep.all():
        return tracks
    return Tracks(
        W=np.ascontiguousarray(tracks.W[:, keep]),
        visibility=np.ascontiguousarray(tracks.visibility[:, keep]),
        colors=np.ascontiguousarray(tracks.colors[keep]),
        frame_size=tracks.frame_size,
        intrinsics=tracks.intrinsics,
    )


def tracks_measurements(tracks: Tracks) -> Measurements:
    """``tracks`` as solver input: W (NaN where lost), visibility, the points' colours, the
    frame size and the intrinsics (the default camera of the frame size when none was
    given)."""
    return Measurements(
        W=tracks.W,
        visibility=tracks.visibility,
        colors=tracks.colors,
        frame_size=tracks.frame_size,
        intrinsics=tracks.intrinsics,
    )
