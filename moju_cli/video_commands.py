"""Video commands of ``moju``: ``track``, and the rendered-video run of ``moju demo --video``.

They need OpenCV (``opencv-python-headless``, the ``video`` extra), imported by
:mod:`moju_core.footage.tracking` and :mod:`moju_core.footage.render` when they run.
"""

from __future__ import annotations

import dataclasses
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

import click
import numpy as np
from tqdm import tqdm

from moju_cli.camera_options import camera_choice, intrinsics_options, resolve_intrinsics
from moju_core.cameras.intrinsics import Intrinsics
from moju_core.errors import VideoError
from moju_core.footage.tracking import (
    DEFAULT_STEP,
    TrackingProgress,
    Tracks,
    track_video,
    write_tracks,
)

#: Size of the rendered video of ``moju demo --video``.
DEMO_VIDEO_SIZE = (320, 240)
#: Frames of ``moju demo --video`` unless --frames says otherwise.
DEMO_VIDEO_FRAMES = 40

# Exit status of a process stopped by SIGINT, as shells report it (128 + signal 2).
_EXIT_INTERRUPTED = 130

F = TypeVar("F", bound=Callable[..., object])


def tracking_options(*, video_only: bool = False) -> Callable[[F], F]:
    """The tracking options --mask, --step, --start and --end, declared once.

    ``moju track`` uses them as they are. ``moju reconstruct`` takes a video or a
    measurement file; with ``video_only`` every default is None, so that the command can tell
    an option given for a measurement file (and refuse it), and the help says "Video only";
    the tracker's defaults apply when they are unset.
    """

    def default(value: object) -> object:
        return None if video_only else value

    def described(text: str, default_text: str | None = None) -> str:
        if not video_only:
            return f"{text[0].upper()}{text[1:]}."
        shown = f" [default: {default_text}]" if default_text is not None else ""
        return f"Video only, as for moju track: {text}{shown}."

    options = [
        click.option(
            "--mask",
            type=click.Path(exists=True, dir_okay=False, path_type=Path),
            default=None,
            help=described(
                "PNG of the first tracked frame's size; non-zero pixels mark the object "
                "[default: the textured region, with a warning]"
            ),
        ),
        click.option(
            "--step",
            type=click.IntRange(min=1),
            default=default(DEFAULT_STEP),
            show_default=not video_only,
            help=described("grid spacing of the tracked points, in pixels", str(DEFAULT_STEP)),
        ),
        click.option(
            "--start",
            type=click.IntRange(min=0),
            default=default(0),
            show_default=not video_only,
            help=described("first frame to track (frames are numbered from 0)", "0"),
        ),
        click.option(
            "--end",
            type=click.IntRange(min=1),
            default=None,
            help=described("frame to stop before (exclusive) [default: the last frame]"),
        ),
    ]

    def decorate(function: F) -> F:
        for option in reversed(options):
            function = option(function)
        return function

    return decorate


def check_frame_range(start: int | None, end: int | None) -> None:
    """Refuse an --end that is not after --start (unset --start: 0)."""
    if end is not None and end <= (start or 0):
        raise click.BadParameter(f"--end ({end}) must be after --start ({start or 0})")


@contextmanager
def _progress_bar(quiet: bool) -> Iterator[tqdm]:
    """A tqdm bar over frames, on stderr; warnings print as ``warning: ...`` lines above it."""
    bar = tqdm(total=None, unit="frame", disable=quiet, leave=False, file=sys.stderr)

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        # The message says what happened; Python's default format adds a source path.
        tqdm.write(f"warning: {message}", file=sys.stderr)

    try:
        with warnings.catch_warnings():
            warnings.showwarning = show
            yield bar
    finally:
        bar.close()


def _require_opencv() -> None:
    """Fail with an install hint, not a traceback, when OpenCV is missing."""
    try:
        import cv2  # noqa: F401
    except ImportError as exc:
        raise click.ClickException(
            "this command needs OpenCV; install it with: pip install 'moju[video]'"
        ) from exc


def _callback(bar: tqdm):
    def update(progress: TrackingProgress) -> None:
        if progress.n_frames is not None and bar.total != progress.n_frames:
            bar.total = progress.n_frames
        bar.set_postfix(tracks=f"{progress.alive}/{progress.n_points}", refresh=False)
        bar.update(progress.frame - bar.n)
        if progress.frame == progress.n_frames:
            bar.refresh()  # tqdm skips redraws closer than 0.1 s; show the bar complete

    return update


def summary(tracks: Tracks, seconds: float) -> str:
    """One line: tracks, frames, what was kept, and the time."""
    to_the_end = int(tracks.visibility[-1].sum())
    return (
        f"{tracks.n_points} tracks over {tracks.n_frames} frames: {tracks.fraction_kept:.1%} of "
        f"the track-frames kept, {to_the_end} tracks ({to_the_end / tracks.n_points:.1%}) "
        f"followed to the last frame; {seconds:.1f} s "
        f"({1000.0 * seconds / tracks.n_frames:.0f} ms per frame)"
    )


def run_tracking(
    video: Path,
    *,
    mask: Path | np.ndarray | None,
    step: int,
    start: int,
    end: int | None,
    method: str,
    quiet: bool,
) -> tuple[Tracks, float]:
    """Track ``video`` with a progress bar; errors of the input become click errors."""
    _require_opencv()
    tic = time.perf_counter()
    try:
        with _progress_bar(quiet) as bar:
            tracks = track_video(
                video,
                mask=mask,
                step=step,
                start=start,
                end=end,
                method=method,  # type: ignore[arg-type]
                callback=_callback(bar),
            )
    except VideoError as exc:
        raise click.ClickException(str(exc)) from exc
    except KeyboardInterrupt:
        click.echo("\ninterrupted; no output written", err=True)
        raise click.exceptions.Exit(_EXIT_INTERRUPTED) from None
    return tracks, time.perf_counter() - tic


def with_intrinsics(tracks: Tracks, intrinsics: Intrinsics | None) -> Tracks:
    """``tracks`` carrying ``intrinsics`` (unchanged when None)."""
    return tracks if intrinsics is None else dataclasses.replace(tracks, intrinsics=intrinsics)


def _check_output(output: Path) -> None:
    if output.suffix.lower() != ".npz":
        raise click.BadParameter(
            f"{output.name!r}: tracks are written as npz; name the file *.npz",
            param_hint="'-o' / '--output'",
        )
    if not output.parent.is_dir():
        raise click.BadParameter(
            f"directory {str(output.parent)!r} does not exist", param_hint="'-o' / '--output'"
        )


def _write(path: Path, tracks: Tracks) -> None:
    try:
        write_tracks(path, tracks)
    except OSError as exc:
        raise click.ClickException(f"could not write {path}: {exc.strerror or exc}") from exc


@click.command("track")
@click.argument("video", type=click.Path(exists=True, path_type=Path))
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Tracks file (npz: W with NaN where lost, visibility, colors, frame_size, and K when "
    "--intrinsics or --focal is given).",
)
@tracking_options()
@intrinsics_options
@click.option(
    "--method",
    type=click.Choice(["dis", "farneback"]),
    default="dis",
    show_default=True,
    help="OpenCV dense optical flow.",
)
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
def track(
    video: Path,
    output: Path,
    mask: Path | None,
    step: int,
    start: int,
    end: int | None,
    intrinsics_file: Path | None,
    focal: float | None,
    method: str,
    quiet: bool,
) -> None:
    """Dense 2D tracks of the object in VIDEO (mp4, webm, avi, or a folder of images).

    A grid of points every --step pixels over the object in frame --start (the --mask, or
    the textured region) is followed by chained optical flow with forward-backward checks and
    re-anchoring to keyframes; a track that fails a check is lost (NaN) from then on.
    Positions are pixels: x to the right, y down, pixel centres at integers. The camera
    matrix given with --intrinsics or --focal is stored with the tracks (K); without one,
    readers take the default camera of the frame size.
    """
    _check_output(output)
    check_frame_range(start, end)
    choice = camera_choice(intrinsics_file, focal)
    tracks, seconds = run_tracking(
        video, mask=mask, step=step, start=start, end=end, method=method, quiet=quiet
    )
    tracks = with_intrinsics(tracks, resolve_intrinsics(choice, tracks.frame_size, video.name))
    _write(output, tracks)
    click.echo(summary(tracks, seconds))
    click.echo(f"tracks: {output}")


def run_video_demo(sequence: str, n_frames: int | None, out_dir: Path, quiet: bool) -> None:
    """``moju demo --video``: render ``sequence``, track the video, score the tracks."""
    _require_opencv()
    import cv2

    from moju_core.footage.render import render_sequence, score_tracks, write_video

    n_frames = DEMO_VIDEO_FRAMES if n_frames is None else n_frames
    width, height = DEMO_VIDEO_SIZE
    tic = time.perf_counter()
    try:
        video = render_sequence(sequence, width=width, height=height, n_frames=n_frames)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from exc
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        video_path = write_video(out_dir / "video.mp4", video.frames)
        mask_path = out_dir / "mask.png"
        if not cv2.imwrite(str(mask_path), video.mask.astype(np.uint8) * 255):
            raise OSError(f"OpenCV could not write {mask_path}")
    except OSError as exc:
        raise click.ClickException(f"could not write to {out_dir}: {exc}") from exc
    click.echo(
        f"{sequence}: rendered {n_frames} frames of {width} x {height} in "
        f"{time.perf_counter() - tic:.1f} s -> {video_path}"
    )
    tracks, seconds = run_tracking(
        video_path,
        mask=mask_path,
        step=DEFAULT_STEP,
        start=0,
        end=None,
        method="dis",
        quiet=quiet,
    )
    tracks_path = out_dir / "tracks.npz"
    _write(tracks_path, tracks)
    click.echo(summary(tracks, seconds))
    scores = score_tracks(video, tracks.W)
    click.echo(
        f"track error against the ground truth (kept track-frames after the first): median "
        f"{scores.median_error:.2f} px, 90th percentile {scores.p90_error:.2f} px"
    )
    click.echo(
        f"kept: {scores.fraction_kept:.1%} of all track-frames, "
        f"{scores.fraction_of_visible_kept:.1%} of those where the point is visible; "
        f"{scores.fraction_kept_occluded:.1%} of the kept ones are hidden in the ground truth"
    )
    click.echo(f"tracks: {tracks_path}")
    click.echo(f"next: moju track {video_path} --mask {mask_path} -o tracks.npz")


COMMANDS = [track]
