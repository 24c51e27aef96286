"""Service commands of ``moju``: ``serve``, ``worker``, ``submit`` and ``api-key``.

The service packages (FastAPI, RQ, httpx) are imported inside the commands, so the solver
commands keep working where only the core dependencies are installed.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

import click

from moju_cli.camera_options import camera_choice, intrinsics_options


def _configure_logging() -> None:
    from service.log_setup import configure_logging

    configure_logging()


def _export_settings(**values: Any) -> None:
    """Put command-line settings into the MOJU_* environment, where every process reads them.

    Forked work horses and child processes read their configuration from the environment
    (:func:`service.settings.get_settings`), so an option set here reaches all of them.
    """
    for name, value in values.items():
        if value is not None:
            os.environ[f"MOJU_{name.upper()}"] = str(value)
    from service.settings import get_settings

    get_settings.cache_clear()


@click.command("serve")
@click.option("--host", default="127.0.0.1", show_default=True, help="Interface of the API.")
@click.option(
    "--port", default=8000, show_default=True, type=click.IntRange(1, 65535), help="API port."
)
@click.option(
    "--workers",
    default=2,
    show_default=True,
    type=click.IntRange(1, 64),
    help="Worker processes (each runs one job at a time).",
)
@click.option(
    "--data-dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Job files and the embedded Redis's data [default: MOJU_DATA_DIR or ./moju-data].",
)
@click.option(
    "--redis-url",
    default=None,
    help="Use this Redis instead of starting one [default: MOJU_REDIS_URL, else embedded].",
)
@click.option(
    "--grace",
    default=10.0,
    show_default=True,
    type=click.FloatRange(0),
    help="Seconds a running job may take to finish when stopping.",
)
def serve(
    host: str, port: int, workers: int, data_dir: Path | None, redis_url: str | None, grace: float
) -> None:
    """Run the whole service: Redis (embedded unless configured), workers and the HTTP API.

    Without MOJU_REDIS_URL (or --redis-url) a private redis-server is started on loopback.
    Ctrl-C stops every process.
    """
    _configure_logging()
    _export_settings(data_dir=data_dir, redis_url=redis_url)
    from service.settings import get_settings
    from service.supervisor import ServeOptions, Supervisor

    settings = get_settings()
    options = ServeOptions(
        host=host,
        port=port,
        workers=workers,
        data_dir=settings.data_dir,
        redis_url=settings.redis_url,
        grace=grace,
        queue_name=settings.queue_name,
    )
    try:
        status = Supervisor(options).run()
    except RuntimeError as exc:
        raise click.ClickException(str(exc)) from exc
    sys.exit(status)


@click.command("worker")
@click.option("--redis-url", default=None, help="Redis of the job queue [default: MOJU_REDIS_URL].")
@click.option(
    "--data-dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Shared job files, as the API's [default: MOJU_DATA_DIR or ./moju-data].",
)
@click.option("--queue", default=None, help="Queue name [default: MOJU_QUEUE_NAME or moju].")
@click.option(
    "--threads",
    type=click.IntRange(1, 256),
    default=None,
    help="BLAS threads per job [default: MOJU_WORKER_THREADS or 1].",
)
@click.option("--burst", is_flag=True, help="Quit when the queue is empty.")
@click.option(
    "--nice",
    "niceness",
    type=click.IntRange(0, 19),
    default=None,
    help="Lower the worker's CPU priority by this much [default: MOJU_WORKER_NICENESS or 0].",
)
def worker(
    redis_url: str | None,
    data_dir: Path | None,
    queue: str | None,
    threads: int | None,
    burst: bool,
    niceness: int | None,
) -> None:
    """Run one worker process that takes reconstruction jobs from the queue."""
    _configure_logging()
    _export_settings(
        redis_url=redis_url,
        data_dir=data_dir,
        queue_name=queue,
        worker_threads=threads,
        worker_niceness=niceness,
    )
    from service.settings import get_settings
    from worker.runner import run_worker

    try:
        get_settings().require_redis_url()
    except RuntimeError as exc:
        raise click.ClickException(f"{exc}; or pass --redis-url") from exc
    run_worker(burst=burst)


def _parse_param(text: str) -> tuple[str, Any]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise click.BadParameter(f"{text!r} is not key=value (e.g. --param max_iter=100)")
    try:
        parsed = json.loads(value)  # numbers, true/false, null
    except json.JSONDecodeError:
        parsed = value  # plain strings such as method=sdg
    return name.strip(), parsed


def _collect_params(param: tuple[str, ...], params_json: Path | None) -> dict[str, Any]:
    from pydantic import ValidationError

    from moju_core.params import SolverParams
    from service.validation_messages import describe_errors

    values: dict[str, Any] = {}
    if params_json is not None:
        try:
            loaded = json.loads(params_json.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise click.BadParameter(f"cannot read {params_json}: {exc}") from exc
        if not isinstance(loaded, dict):
            raise click.BadParameter(f"{params_json} must hold a JSON object")
        values.update(loaded)
    values.update(_parse_param(item) for item in param)
    try:
        SolverParams.model_validate(values)  # fail here, before uploading anything
    except ValidationError as exc:
        raise click.BadParameter(describe_errors(exc.errors(), parameters_at=None)) from exc
    return values


class _ProgressBar:
    """A tqdm bar fed with the job resources the client receives."""

    def __init__(self) -> None:
        from tqdm import tqdm

        self.bar = tqdm(
            total=100, desc="queued", bar_format="{desc} |{bar}| {percentage:3.0f}% {elapsed}"
        )

    def __call__(self, job: Any) -> None:
        text = job.status.value
        progress = job.progress
        if progress is not None:
            self.bar.n = round(100 * progress.fraction, 1)
            # A finished job's last stage is "finished" too: say it once.
            if progress.stage != text:
                text += f" {progress.stage}"
            text += f" {progress.iteration}/{progress.max_iter}"
            if progress.gap is not None:
                text += f" gap {progress.gap:.1e}"
            if progress.eta is not None and job.status.value == "running":
                text += f" eta {progress.eta:.0f}s"
        self.bar.set_description_str(text, refresh=True)

    def close(self) -> None:
        self.bar.close()


#: How ``moju submit`` names where the job's camera came from.
_CAMERA_SOURCES = {
    "focal": "from --focal",
    "intrinsics": "from --intrinsics",
    "file": "K of the input",
    "default": "default: 1.2 x the larger image side; give --focal or --intrinsics",
}


def _camera_line(K: list[list[float]], source: str) -> str:
    """One line: the camera the job solves with, as ``moju reconstruct`` prints it."""
    (fx, _, cx), (_, fy, cy), _ = K
    return (
        f"camera: focal {fx:g} x {fy:g} px, principal point ({cx:g}, {cy:g}) "
        f"({_CAMERA_SOURCES.get(source, source)})"
    )


@click.command("submit")
@click.argument("input_file", metavar="INPUT", type=click.Path(exists=True, dir_okay=False))
@click.option(
    "--server",
    envvar="MOJU_SERVER",
    default="http://127.0.0.1:8000",
    show_default=True,
    help="Base URL of the service (env MOJU_SERVER).",
)
@click.option(
    "--api-key",
    envvar="MOJU_API_KEY",
    default=None,
    help="API key, for a server that needs one (env MOJU_API_KEY).",
)
@click.option("--param", multiple=True, help="Solver parameter key=value (repeatable).")
@click.option(
    "--params-json",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="JSON file with solver parameters (--param overrides it).",
)
@click.option(
    "--mask",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help=(
        "With a video INPUT: PNG of the first frame's size, non-zero (or opaque) on the "
        "object to track."
    ),
)
@intrinsics_options
@click.option("--wait", is_flag=True, help="Follow the job until it ends.")
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Download the result here (.npz or .h5); implies --wait.",
)
def submit(
    input_file: str,
    server: str,
    api_key: str | None,
    param: tuple[str, ...],
    params_json: Path | None,
    mask: Path | None,
    intrinsics_file: Path | None,
    focal: float | None,
    wait: bool,
    output: Path | None,
) -> None:
    """Upload INPUT (npz, HDF5 or CSV tracks, or a video: mp4, webm or avi, tracked by the
    service first) to a MoJu service as a job.

    The camera: --focal PIXELS or --intrinsics FILE, as for moju track and moju reconstruct
    (checked before anything is uploaded); given, it replaces the K of a tracks file.
    """
    from moju_cli.stop_reasons import describe_stop
    from service.client import MojuClient, MojuError

    if output is not None and output.suffix.lower() not in (".npz", ".h5", ".hdf5"):
        raise click.BadParameter("use the extension .npz, .h5 or .hdf5", param_hint="-o")
    params = _collect_params(param, params_json)
    camera_choice(intrinsics_file, focal)  # both given, or a file that is no K: refused here
    job = None
    with MojuClient(server, api_key=api_key) as client:
        try:
            job = client.submit(
                input_file, params or None, mask=mask, focal=focal, intrinsics=intrinsics_file
            )
            click.echo(f"job {job.id} {job.status.value} ({job.input.frames} frames x "
                       f"{job.input.points} points)")  # fmt: skip
            if job.input.camera is not None:
                click.echo(_camera_line(job.input.camera.K, job.input.camera.source))
            if not (wait or output):
                click.echo(f"follow it: {server.rstrip('/')}/v1/jobs/{job.id}")
                return
            bar = _ProgressBar()
            try:
                job = client.wait(job.id, on_progress=bar)
            finally:
                bar.close()
            resolved = job.result.resolved_parameters
            reason = describe_stop(
                str(job.result.stop_reason),
                method=resolved.method,
                tol=resolved.tol,
                shape_gap=job.result.shape_gap,
                exact_fit=job.result.exact_fit,
            )
            click.echo(f"job {job.id} finished: {job.result.n_iter} iterations, {reason}")
            if output is not None:
                client.download(job.id, output)
                click.echo(f"result written to {output}")
        except MojuError as exc:  # includes JobFailed and JobCancelled
            raise click.ClickException(str(exc)) from exc
        except KeyboardInterrupt:
            if job is not None:
                click.echo(
                    f"\nstopped following; the job continues on the server (cancel it with "
                    f"curl -X DELETE {server.rstrip('/')}/v1/jobs/{job.id})",
                    err=True,
                )
            sys.exit(130)


@click.command("api-key")
@click.option(
    "--hash",
    "key_to_hash",
    default=None,
    metavar="KEY",
    help="Print the configuration entry (sha256:...) of an existing key instead.",
)
def api_key(key_to_hash: str | None) -> None:
    """Make a new API key and print it with its entry for MOJU_API_KEYS.

    The key goes to the client (moju submit --api-key, or MOJU_API_KEY); the server needs
    only the entry "sha256:<digest>" (in MOJU_API_KEYS or a line of MOJU_API_KEYS_FILE).
    """
    import secrets

    from service.auth import MIN_KEY_LENGTH, key_digest

    if key_to_hash is not None:
        if len(key_to_hash) < MIN_KEY_LENGTH:
            raise click.BadParameter(f"keys have at least {MIN_KEY_LENGTH} characters")
        click.echo(f"sha256:{key_digest(key_to_hash)}")
        return
    key = secrets.token_urlsafe(32)
    click.echo(f"key:   {key}")
    click.echo(f"entry: sha256:{key_digest(key)}")


COMMANDS = [serve, worker, submit, api_key]
