"""Solver commands of ``moju``: ``reconstruct``, ``evaluate`` and ``demo``.

They need only the core dependencies (numpy, scipy, scikit-learn, h5py, plyfile, pydantic,
click, tqdm). The solver options of ``moju reconstruct`` are generated from
:class:`moju_core.params.SolverParams`, the one parameter schema: every field becomes an option
(``max_iter`` -> ``--max-iter``) with the field's description and default, and the values are
validated by the schema itself, so the CLI can never drift from the library, the API and the
worker.
"""

from __future__ import annotations

import contextlib
import json
import sys
import time
import types
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

import click
import numpy as np
from pydantic import ValidationError
from pydantic.fields import FieldInfo
from tqdm import tqdm

from moju_cli.camera_options import (
    CameraChoice,
    camera_choice,
    intrinsics_options,
    resolve_intrinsics,
)
from moju_cli.stop_reasons import describe_stop
from moju_cli.video_commands import check_frame_range, tracking_options
from moju_core import defaults
from moju_core.cameras.intrinsics import Intrinsics
from moju_core.datasets import (
    BODY_SEQUENCE_NAMES,
    HARD_SEQUENCE_NAMES,
    SEQUENCE_NAMES,
    make_sequence,
)
from moju_core.errors import MeasurementError
from moju_core.footage.tracking import (
    DEFAULT_STEP,
    solvable_tracks,
    tracks_measurements,
    write_tracks,
)
from moju_core.footage.video import is_video_source
from moju_core.io import Measurements, read_measurements, read_result, write_measurements
from moju_core.io import write_result as write_result_file
from moju_core.metrics import evaluate as evaluate_scores
from moju_core.params import SolverParams, rotation_method
from moju_core.perspective import used_camera
from moju_core.ply import frame_file_name, write_ply_frames
from moju_core.result import Diagnostics, Progress, Result

#: Extensions :func:`moju_core.io.write_result` understands; checked before any solving.
RESULT_EXTENSIONS = (".npz", ".h5", ".hdf5")

#: Size of ``moju demo``'s default sequence: large enough to be "dense" (a visible surface in
#: the PLY files), small enough for the whole demo to take a few seconds (2-3 s on one thread of
#: a two-core machine, of which the solve is about 1 s).
DEMO_POINTS = 5_000

#: BLAS/OpenMP threads of the solver unless --threads says otherwise. One, as the service's
#: workers: the ADMM loop runs many small matrix products, and with two OpenBLAS threads it ran
#: 1.7 to 20 times slower than with one (a busy two-core machine, face and paper sequences of
#: 300 to 28,880 points).
DEFAULT_THREADS = 1

#: Exit status of a process stopped by SIGINT, as shells report it (128 + signal 2).
EXIT_INTERRUPTED = 130

#: Labels of the scores of :func:`moju_core.metrics.evaluate`, in printing order.
SCORE_LABELS = {
    "e3d_procrustes": "e3D, per-frame Procrustes alignment",
    "e3d_global": "e3D, one global alignment",
    "e3d_sign": "e3D, depth sign only",
    "observed_fraction": "observed (frame, point) entries",
    "e3d_occluded_procrustes": "e3D of the occluded entries, Procrustes",
    "e3d_occluded_global": "e3D of the occluded entries, global",
    "e3d_occluded_sign": "e3D of the occluded entries, depth sign",
    "rotation_error_deg": "rotation error (degrees)",
}

# Command-line additions to a field's schema description, where the CLI adds a meaning.
_CLI_NOTES = {
    "rotations": "'known' (and the default, when INPUT has one) uses the dataset R of INPUT; "
    "with an estimating method, R is only scored against."
}

F = TypeVar("F", bound=Callable[..., Any])


# --------------------------------------------------------------------------------------------
# Solver options generated from SolverParams


def _option_name(field_name: str) -> str:
    return "--" + field_name.replace("_", "-")


def _click_type(annotation: Any) -> click.ParamType:
    """Click type of a :class:`SolverParams` field: choices for literals, else bool, int or float.

    Range constraints are not copied into the click type: the schema checks them (once, in
    :func:`_solver_params`), so there is a single definition of every bound.
    """
    candidates = [annotation]
    if get_origin(annotation) in (Union, types.UnionType):
        candidates = [arg for arg in get_args(annotation) if arg is not type(None)]
    if len(candidates) == 1:
        kind = candidates[0]
        if get_origin(kind) is Literal:
            return click.Choice([str(value) for value in get_args(kind)])
        if kind is bool:
            return click.BOOL  # --free-mean-shape false
        if kind is int:
            return click.INT
        if kind is float:
            return click.FLOAT
    # Fail at import time: a new field type must get a deliberate command-line form.
    raise TypeError(f"no command-line type for a SolverParams field of type {annotation!r}")


def _option_help(name: str, field: FieldInfo) -> str:
    parts = [field.description or name]
    if name in _CLI_NOTES:
        parts.append(_CLI_NOTES[name])
    default = field.default
    if default is None:
        default = "derived from the data"
    elif isinstance(default, float):
        default = f"{default:g}"
    parts.append(f"[default: {default}]")
    return " ".join(parts)


def _solver_option(name: str) -> Callable[[F], F]:
    """A click option for the :class:`SolverParams` field ``name``.

    The option's own default is None so that only the values a user typed reach the schema:
    the schema applies its defaults, and ``model_fields_set`` tells typed from default.
    """
    field = SolverParams.model_fields[name]
    return click.option(
        _option_name(name),
        name,
        type=_click_type(field.annotation),
        default=None,
        help=_option_help(name, field),
    )


def _solver_options(function: F) -> F:
    """Add one option per :class:`SolverParams` field, in the schema's order."""
    for name in reversed(SolverParams.model_fields):
        function = _solver_option(name)(function)
    return function


def _solver_params(values: dict[str, Any]) -> SolverParams:
    """Validate the typed solver options with the schema; a violation is a usage error."""
    typed = {name: value for name, value in values.items() if value is not None}
    try:
        return SolverParams(**typed)
    except ValidationError as exc:
        problems = []
        for error in exc.errors():
            location = error["loc"][0] if error["loc"] else ""
            option = _option_name(str(location)) if location else "parameters"
            problems.append(f"{option} {error.get('input')!r}: {error['msg']}")
        raise click.UsageError("invalid solver parameter: " + "; ".join(problems)) from exc


def _pop_solver_values(kwargs: dict[str, Any]) -> dict[str, Any]:
    return {name: kwargs.pop(name) for name in SolverParams.model_fields}


# --------------------------------------------------------------------------------------------
# Running the solver: progress bar, Ctrl-C, outputs


class _ProgressBar:
    """A tqdm bar on stderr, fed by the solver's progress callback.

    The bar counts ADMM iterations against :func:`moju_core.defaults.expected_iterations`
    (the iterations until the penalty reaches ``rho_max``), which is exact unless the gap
    converges first; it then jumps to the end. While iterating it shows the gap the solver
    reports (the larger of the shape and coefficient gaps); at the end, the last shape gap,
    the one the convergence test compares with ``tol`` (:meth:`finish`).
    """

    def __init__(self, params: SolverParams, enabled: bool) -> None:
        self.stage = ""
        self.bar = tqdm(
            total=defaults.expected_iterations(params),
            desc="starting",
            unit="it",
            file=sys.stderr,
            disable=not enabled,
            dynamic_ncols=True,
        )

    def __call__(self, progress: Progress) -> None:
        if progress.stage != self.stage:
            self.stage = progress.stage
            self.bar.set_description_str(progress.stage)
        if progress.stage == "iterating":
            if progress.iteration > self.bar.total:
                self.bar.total = progress.iteration
            self.bar.update(progress.iteration - self.bar.n)
            self.bar.set_postfix_str(f"gap={progress.gap:.1e}", refresh=False)
        elif progress.stage == "finishing":
            # An early convergence ends the loop before the expected count: show it complete.
            self.bar.total = max(self.bar.n, 1)
            self.bar.refresh()

    def finish(self, result: Result) -> None:
        """Show the last shape gap of ``result``, which the stop reason is about."""
        shape_gap = result.final_shape_gap
        if shape_gap is not None and self.bar.n:
            self.bar.set_postfix_str(f"shape gap={shape_gap:.1e}", refresh=True)

    def warn(
        self,
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: Any = None,
        line: str | None = None,
    ) -> None:
        """Print a solver warning as one line, above the bar (a :func:`warnings.showwarning`)."""
        # The default format shows the library's source path and line, which means nothing
        # to a command-line user; the message itself says what happened.
        tqdm.write(f"warning: {message}", file=sys.stderr)

    def close(self) -> None:
        self.bar.close()


def _solve(
    W: np.ndarray,
    params: SolverParams,
    rotations: np.ndarray | None,
    *,
    quiet: bool,
    threads: int,
    visibility: np.ndarray | None = None,
    intrinsics: Intrinsics | None = None,
) -> Result:
    """Run :func:`moju_core.reconstruct` with a progress bar on ``threads`` BLAS threads.

    ``visibility`` (F, P) bool marks the observed entries of W (None: all observed).
    ``intrinsics`` is the camera resolved for W's pixels (None: orthographic tracks); with it
    the solve is perspective (:mod:`moju_core.perspective`).
    Input errors become CLI errors; solver warnings are printed as ``warning: ...`` lines.
    """
    # Imported here: the solver pulls in scikit-learn, which ``moju --help`` should not wait for.
    from moju_core import reconstruct

    bar = _ProgressBar(params, enabled=not quiet)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = bar.warn
            # Complete data go through the call as before; a mask only when something is missing.
            # A mask and a camera only when there is one: complete orthographic tracks go
            # through the call as before.
            masked = {} if visibility is None else {"visibility": visibility}
            camera = {} if intrinsics is None else {"intrinsics": intrinsics}
            result = reconstruct(
                W, params, rotations=rotations, callback=bar, threads=threads, **masked, **camera
            )
        bar.finish(result)
        return result
    except MeasurementError as exc:
        raise click.ClickException(str(exc)) from exc
    finally:
        bar.close()


class _Outputs:
    """Files a command writes; on Ctrl-C the ones it created are removed again.

    Every single file is written atomically by moju_core (temporary name, then rename), but a
    run writes several (result, PLY frames, the demo's input); an interrupted run must not
    leave an incomplete set behind, so what this run created is deleted.
    """

    def __init__(self) -> None:
        self.created: list[Path] = []
        self.directories: list[Path] = []

    def make_directory(self, directory: Path) -> None:
        """Create ``directory`` (and missing parents), remembering which ones are new."""
        missing = [path for path in (directory, *directory.parents) if not path.exists()]
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise click.ClickException(f"could not create {directory}: {exc.strerror}") from exc
        # Outermost first, so that remove() can delete innermost first.
        self.directories.extend(reversed(missing))

    def write_result(self, path: Path, result: Result, metadata: dict[str, Any]) -> None:
        self.created.append(path)
        _write_or_fail(path, lambda: write_result_file(path, result, metadata=metadata))

    def write_measurements(self, path: Path, measurements: Measurements) -> None:
        self.created.append(path)
        _write_or_fail(path, lambda: write_measurements(path, measurements))

    def write_ply(
        self,
        directory: Path,
        shapes: np.ndarray,
        faces: np.ndarray | None,
        colors: np.ndarray | None,
    ) -> list[Path]:
        n_frames = shapes.shape[0]
        self.make_directory(directory)
        # Frames left by an earlier run under the same names are not this run's to delete.
        self.created.extend(
            path
            for path in (directory / frame_file_name(f, n_frames) for f in range(n_frames))
            if not path.exists()
        )
        return _write_or_fail(
            directory, lambda: write_ply_frames(directory, shapes, faces=faces, colors=colors)
        )

    def remove(self) -> None:
        for path in self.created:
            path.unlink(missing_ok=True)
        for directory in reversed(self.directories):
            # Only directories this run created are recorded, and rmdir refuses non-empty
            # ones, so nothing of the user's is removed.
            with contextlib.suppress(OSError):
                directory.rmdir()


def _write_or_fail(path: Path, write: Callable[[], Any]) -> Any:
    try:
        return write()
    except OSError as exc:
        raise click.ClickException(f"could not write {path}: {exc.strerror or exc}") from exc


@contextlib.contextmanager
def _interruptible(outputs: _Outputs) -> Iterator[None]:
    """Turn Ctrl-C into exit status 130 with a one-line message and no partial outputs.

    Also removes this run's files when a write fails half-way, for the same reason.
    """
    try:
        yield
    except KeyboardInterrupt:
        outputs.remove()
        click.echo("\ninterrupted; no output written", err=True)
        raise click.exceptions.Exit(EXIT_INTERRUPTED) from None
    except click.ClickException:
        outputs.remove()
        raise


def _check_output(output: Path) -> None:
    """Refuse an output that :func:`moju_core.io.write_result` could not write, before solving."""
    if output.suffix.lower() not in RESULT_EXTENSIONS:
        raise click.BadParameter(
            f"{output.name!r} has no result extension; use one of {', '.join(RESULT_EXTENSIONS)}",
            param_hint="'-o' / '--output'",
        )
    parent = output.parent
    if not parent.is_dir():
        raise click.BadParameter(
            f"directory {str(parent)!r} does not exist", param_hint="'-o' / '--output'"
        )


def _threads_option(function: F) -> F:
    return click.option(
        "--threads",
        type=click.IntRange(min=1),
        default=DEFAULT_THREADS,
        show_default=True,
        help="BLAS/OpenMP threads of the solver (more were slower in our measurements).",
    )(function)


def _format_scores(scores: dict[str, float], *, rotations_estimated: bool) -> list[str]:
    """Text lines of :func:`moju_core.metrics.evaluate` scores, one per score."""
    width = max(len(SCORE_LABELS[key]) for key in scores)
    lines = []
    for key, label in SCORE_LABELS.items():
        if key in scores:
            value = f"{scores[key]:.4f}"
            if key == "rotation_error_deg":
                value = f"{scores[key]:.2f}"
            elif key == "observed_fraction":
                value = f"{100 * scores[key]:.1f} %"
            lines.append(f"{label + ':':<{width + 1}} {value}")
    if rotations_estimated:
        # Estimated rotations fix the shapes only up to one global rotation, which the sign
        # mode does not remove; without this note a large number there looks like a failure.
        lines.append(
            "(the depth-sign e3D compares in the true camera frame: it is only meaningful for "
            "known rotations)"
        )
    return lines


def _summary(result: Result, n_frames: int, n_points: int, observed: float = 1.0) -> str:
    reason = describe_stop(
        str(result.stop_reason),
        method=result.params.method,
        tol=result.params.tol,
        shape_gap=result.final_shape_gap,
        exact_fit=result.exact_fit,
    )
    seen = f" ({100 * observed:.1f} % observed)" if observed < 1.0 else ""
    line = (
        f"{n_frames} frames x {n_points} points{seen}: {result.n_iter} "
        f"iteration{'' if result.n_iter == 1 else 's'}, {reason}, "
        f"{result.timings['total']:.1f} s"
    )
    completion = _completion_line(result.diagnostics)
    return line if completion is None else f"{line}\n{completion}"


def _completion_line(diagnostics: Diagnostics | None) -> str | None:
    """How the hidden entries were completed, for a reader judging the filled-in points; None
    when nothing was hidden (or the result records no diagnostics)."""
    if diagnostics is None or diagnostics.completion_rank is None:
        return None
    rank = diagnostics.completion_rank
    if diagnostics.exact_completion:
        return f"hidden entries: completed by an exact rank-{rank} model of the tracks"
    unexplained = diagnostics.completion_unexplained or 0.0
    return (
        f"hidden entries: completed by a rank-{rank} model, whose error on held-out observed "
        f"entries beyond the noise is {100 * unexplained:.1f} % of a rank-1 model's"
    )


def _occlusion_mask(used: np.ndarray | None, of_input: np.ndarray | None) -> np.ndarray | None:
    """The visibility to score the occluded entries by: the one the solver used (the result's)
    when it misses something, else the input's; None when neither does."""
    for mask in (used, of_input):
        if mask is not None and not np.all(mask):
            return np.asarray(mask, dtype=bool)
    return None


# --------------------------------------------------------------------------------------------
# Commands


@click.command("reconstruct")
@click.argument("input_file", metavar="INPUT", type=click.Path(exists=True))
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help=f"Result file: {', '.join(RESULT_EXTENSIONS)} (format by extension).",
)
@click.option(
    "--ply-dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Also write one PLY per frame here (with INPUT's faces and colors when present; "
    "for a video, coloured from its first frame).",
)
@tracking_options(video_only=True)
@intrinsics_options
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
@_threads_option
@_solver_options
def reconstruct(
    input_file: str,
    output: Path,
    ply_dir: Path | None,
    mask: Path | None,
    step: int | None,
    start: int | None,
    end: int | None,
    intrinsics_file: Path | None,
    focal: float | None,
    quiet: bool,
    threads: int,
    **solver_values: Any,
) -> None:
    """Reconstruct 3D shapes and camera rotations from the 2D tracks in INPUT, or from a video.

    INPUT is npz, HDF5 (dataset W of shape 2F x P, or tracks F x P x 2; optional R, gt,
    faces, colors) or CSV (header frame,point,x,y). Solver options left unset take the
    schema's defaults; those marked "derived from the data" are chosen from the input's size.
    When INPUT holds ground truth (gt), the e3D is printed.

    INPUT may also be a video (mp4, webm, avi) or a folder of images: it is tracked first as
    by moju track (--mask, --step, --start, --end), the tracks are written next to the result
    (OUTPUT's name with .tracks.npz), and the lost positions are solved for as missing
    entries. From a video or a tracks file alike, tracks seen in fewer than 2 frames are left
    out, with a warning that says how many.

    The camera: --intrinsics FILE or --focal PIXELS, else the K stored in INPUT, else, for a
    video or tracks with a frame size, the default (focal 1.2 x the larger image side,
    principal point at the image centre); the one used is recorded in the result's metadata.
    """
    _check_output(output)
    video = is_video_source(input_file)
    _check_video_options(video, mask=mask, step=step, start=start, end=end)
    choice = camera_choice(intrinsics_file, focal)
    params = _solver_params(_pop_solver_values(solver_values))
    if video and params.rotations == "known":
        raise click.UsageError(
            "--rotations known needs camera rotations, which a video does not have; use "
            "--rotations auto (or leave it unset) to estimate them"
        )
    outputs = _Outputs()
    tracks_path = None
    with _interruptible(outputs):
        if video:
            tracks_path = output.with_name(output.stem + ".tracks.npz")
            measurements = _track_video_input(
                Path(input_file),
                tracks_path,
                outputs,
                mask=mask,
                step=DEFAULT_STEP if step is None else step,
                start=start or 0,
                end=end,
                quiet=quiet,
                choice=choice,
            )
        else:
            measurements = _read_input(Path(input_file), choice)
        # The library's rule: R of INPUT is used unless an estimating method is named, in
        # which case R is only the truth the estimated rotations are scored against.
        method = rotation_method(params.rotations, measurements.rotations is not None)
        known = method == "known"
        if known and measurements.rotations is None:
            raise click.ClickException(
                f"--rotations known needs the camera rotations, but {Path(input_file).name} "
                f"has no dataset R (shape {measurements.n_frames} x 2 x 3); add it, or use "
                "--rotations auto to estimate them"
            )
        # The camera of W's pixels: --intrinsics / --focal, else INPUT's K, else the default
        # of its frame size; None for tracks without a frame size (orthographic).
        intrinsics = measurements.intrinsics
        result = _solve(
            measurements.W,
            params,
            measurements.rotations if known else None,
            quiet=quiet,
            threads=threads,
            visibility=measurements.visibility,
            intrinsics=intrinsics,
        )
        metadata: dict[str, Any] = {
            "input": Path(input_file).name,
            "created_by": "moju reconstruct",
        }
        if intrinsics is not None:  # the camera the solve used: an estimated focal length too
            intrinsics = used_camera(intrinsics, result)
            metadata["intrinsics"] = intrinsics.to_metadata()
        outputs.write_result(output, result, metadata)
        if ply_dir is not None:
            outputs.write_ply(ply_dir, result.shapes, measurements.faces, measurements.colors)
    # Reported only once everything is written: an interrupted run names no files.
    click.echo(
        _summary(
            result, measurements.n_frames, measurements.n_points, measurements.observed_fraction
        )
    )
    if intrinsics is not None:
        click.echo(_camera_line(intrinsics))
    if tracks_path is not None:
        click.echo(f"tracks: {tracks_path}")
    click.echo(f"result: {output}")
    if ply_dir is not None:
        click.echo(f"PLY: {measurements.n_frames} files in {ply_dir}")
    if measurements.ground_truth is not None:
        # Against estimated rotations only: with known ones the error is zero by construction.
        with_rotations = measurements.rotations is not None and not known
        scores = evaluate_scores(
            result.shapes,
            measurements.ground_truth,
            result.rotations if with_rotations else None,
            measurements.rotations if with_rotations else None,
            visibility=_occlusion_mask(result.visibility, measurements.visibility),
        )
        for line in _format_scores(scores, rotations_estimated=not known):
            click.echo(line)


def _camera_line(intrinsics: Intrinsics) -> str:
    """One line: the camera used and where it came from."""
    cx, cy = intrinsics.principal_point
    origin = {
        "given": "given",
        "focal": "from --focal",
        "default": "default: 1.2 x the larger image side; give --focal or --intrinsics",
        "estimated": "estimated from the tracks; give --focal or --intrinsics if known",
    }[intrinsics.origin]
    return (
        f"camera: focal {intrinsics.fx:g} x {intrinsics.fy:g} px, principal point "
        f"({cx:g}, {cy:g}) ({origin})"
    )


@contextlib.contextmanager
def _printed_warnings() -> Iterator[None]:
    """Print the warnings raised inside as ``warning: ...`` lines on stderr."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        click.echo(f"warning: {message}", err=True)

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = show
        yield


def _read_input(path: Path, choice: CameraChoice) -> Measurements:
    """Read a measurement file, leaving out (with a warning) the tracks seen in one frame
    only, as for a video; the camera of the command line replaces the file's."""
    try:
        with _printed_warnings():
            measurements = read_measurements(path, short_tracks="drop")
    except MeasurementError as exc:
        raise click.ClickException(str(exc)) from exc
    given = resolve_intrinsics(choice, measurements.frame_size, path.name)
    if given is not None:
        measurements.intrinsics = given
    return measurements


def _check_video_options(video: bool, **options: Any) -> None:
    """Refuse tracking options for a measurement file, and an --end not after --start."""
    given = [name for name, value in options.items() if value is not None]
    if not video and given:
        names = ", ".join(f"--{name}" for name in given)
        raise click.UsageError(
            f"{names} only apply to a video input (mp4, webm, avi or a folder of images); "
            "INPUT is a measurement file"
        )
    check_frame_range(options["start"], options["end"])


def _track_video_input(
    video: Path,
    tracks_path: Path,
    outputs: _Outputs,
    *,
    mask: Path | None,
    step: int,
    start: int,
    end: int | None,
    quiet: bool,
    choice: CameraChoice,
) -> Measurements:
    """Track ``video`` (as ``moju track``), write the solvable tracks (with the camera of the
    command line, if any) to ``tracks_path`` and return them as measurements (NaN where lost,
    the first frame's colours, the frame size and the camera)."""
    from moju_cli.video_commands import run_tracking, summary, with_intrinsics

    tracks, seconds = run_tracking(
        video, mask=mask, step=step, start=start, end=end, method="dis", quiet=quiet
    )
    click.echo(summary(tracks, seconds))
    tracks = with_intrinsics(tracks, resolve_intrinsics(choice, tracks.frame_size, video.name))
    try:
        with _printed_warnings():
            kept = solvable_tracks(tracks)
    except MeasurementError as exc:
        raise click.ClickException(str(exc)) from exc
    outputs.created.append(tracks_path)
    _write_or_fail(tracks_path, lambda: write_tracks(tracks_path, kept))
    try:
        return tracks_measurements(kept)
    except MeasurementError as exc:
        raise click.ClickException(str(exc)) from exc


@click.command("evaluate")
@click.argument("result_file", metavar="RESULT", type=click.Path(exists=True, dir_okay=False))
@click.option(
    "--gt",
    "truth_file",
    metavar="INPUT",
    required=True,
    type=click.Path(exists=True, dir_okay=False),
    help="Input file holding the ground truth gt (and R for the rotation error).",
)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of text.")
def evaluate(result_file: str, truth_file: str, as_json: bool) -> None:
    """Compare the shapes of RESULT with the ground truth in INPUT.

    Prints the e3D (paper Eq. 17) after per-frame Procrustes alignment, after one global
    alignment, and after fixing only the depth sign, plus the mean camera rotation error in
    degrees when INPUT holds R. When points were missing (the visibility of RESULT, else that
    of INPUT, has unobserved entries), also the fraction observed and the e3D over the occluded
    entries alone, each frame relative to its occluded ground-truth points.
    """
    try:
        result = read_result(result_file)
    except (OSError, ValueError) as exc:
        raise click.ClickException(str(exc)) from exc
    try:
        # The points moju reconstruct kept: tracks seen in one frame only are left out.
        with _printed_warnings():
            measurements = read_measurements(truth_file, short_tracks="drop")
    except MeasurementError as exc:
        raise click.ClickException(str(exc)) from exc
    if measurements.ground_truth is None:
        raise click.ClickException(
            f"{Path(truth_file).name} has no ground truth: it needs a dataset gt of shape "
            f"(F, P, 3) = ({measurements.n_frames}, {measurements.n_points}, 3)"
        )
    with_rotations = measurements.rotations is not None
    try:
        scores = evaluate_scores(
            result.shapes,
            measurements.ground_truth,
            result.rotations if with_rotations else None,
            measurements.rotations,
            visibility=_occlusion_mask(result.visibility, measurements.visibility),
        )
    except ValueError as exc:  # shapes of the two files disagree
        raise click.ClickException(
            f"{Path(result_file).name} does not match {Path(truth_file).name}: {exc}"
        ) from exc
    if as_json:
        click.echo(json.dumps(scores))
        return
    estimated = result.params.rotations != "known"
    for line in _format_scores(scores, rotations_estimated=estimated):
        click.echo(line)


@click.command("demo")
@click.option(
    "--sequence",
    type=click.Choice(SEQUENCE_NAMES + HARD_SEQUENCE_NAMES + BODY_SEQUENCE_NAMES),
    default="face1",
    show_default=True,
    help="Synthetic sequence (face1: 10 frames of a face-like surface, +-30 degrees of yaw).",
)
@click.option(
    "--points",
    type=click.IntRange(min=4),
    default=DEMO_POINTS,
    show_default=True,
    help="Number of points; the default runs in a few seconds on a laptop.",
)
@click.option(
    "--frames",
    type=click.IntRange(min=2),
    default=None,
    help="Number of frames [default: the sequence's own, 10 for face1].",
)
@click.option(
    "--noise",
    type=click.FloatRange(min=0.0),
    default=0.0,
    show_default=True,
    help="Gaussian track noise, as a fraction of the largest track coordinate.",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("moju-demo"),
    show_default=True,
    help="Directory for input.npz, result.npz and ply/.",
)
@_solver_option("method")
@click.option(
    "--video",
    is_flag=True,
    help="Render the sequence into OUT/video.mp4 (320 x 240, 40 frames unless --frames), "
    "track it and report the track errors against the ground truth (no reconstruction).",
)
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
@_threads_option
def demo(
    sequence: str,
    points: int,
    frames: int | None,
    noise: float,
    out_dir: Path,
    method: str | None,
    video: bool,
    quiet: bool,
    threads: int,
) -> None:
    """Reconstruct a synthetic sequence with ground truth and report the errors.

    Writes OUT/input.npz (tracks W, true rotations R, ground truth gt, faces, colors),
    reconstructs with estimated rotations (the default, rotations="auto"), prints the e3D
    and the rotation error, and writes OUT/result.npz and one PLY per frame to OUT/ply/.
    With --video: see moju_cli.video_commands.run_video_demo.
    """
    if video:
        from moju_cli.video_commands import run_video_demo

        if sequence in BODY_SEQUENCE_NAMES:
            raise click.UsageError(
                f"--video renders a textured surface; {sequence} is markers without one: "
                "choose a face or a sheet, or drop --video"
            )

        run_video_demo(sequence, frames, out_dir, quiet)
        return
    params = _solver_params({"method": method, "rotations": "auto"})
    outputs = _Outputs()
    with _interruptible(outputs):
        tic = time.perf_counter()
        try:
            data = make_sequence(sequence, n_frames=frames, n_points=points, noise=noise)
        except ValueError as exc:  # e.g. --noise inf, which click's range lets through
            raise click.UsageError(str(exc)) from exc
        n_frames, n_points = data.shapes.shape[:2]
        outputs.make_directory(out_dir)
        input_path = out_dir / "input.npz"
        outputs.write_measurements(
            input_path,
            Measurements(
                W=data.W,
                rotations=data.rotations,
                ground_truth=data.shapes,
                faces=data.faces,
                colors=data.colors,
            ),
        )
        click.echo(
            f"{sequence}: {n_frames} frames x {n_points} points, noise {noise:g} -> {input_path}"
        )
        result = _solve(data.W, params, None, quiet=quiet, threads=threads)
        click.echo(_summary(result, n_frames, n_points))
        scores = evaluate_scores(result.shapes, data.shapes, result.rotations, data.rotations)
        for line in _format_scores(scores, rotations_estimated=True):
            click.echo(line)
        result_path = out_dir / "result.npz"
        metadata = {"sequence": sequence, "noise": noise, "created_by": "moju demo"}
        outputs.write_result(result_path, result, metadata)
        ply_dir = out_dir / "ply"
        paths = outputs.write_ply(ply_dir, result.shapes, data.faces, data.colors)
    click.echo(f"result: {result_path}")
    click.echo(f"PLY: {len(paths)} files in {ply_dir}")
    click.echo(f"total time: {time.perf_counter() - tic:.1f} s")
    click.echo(f"next: moju evaluate {result_path} --gt {input_path}")


COMMANDS = [reconstruct, evaluate, demo]
