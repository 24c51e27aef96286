"""What every benchmark script shares: one way to run a method on a sequence and record its
metrics, the run's provenance (machine, library versions, command) and the writers of the
result files.

A measurement is a flat dictionary (a "row"): the sequence and its size, the noise level, the
rotations used, the method and any parameter overrides, e3D in two alignments, the camera
rotation error, the wall time and the solver's own timings, iterations, stop reason and the
resolved parameters that matter for reading the number (groups, p, the PTA basis size, the
temporal prior's weight, which rotation estimate the camera step chose).
"""

from __future__ import annotations

import json
import os
import platform
import shlex
import sys
import time
import warnings
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from moju_core import SolverParams, reconstruct
from moju_core.datasets import Sequence as Dataset
from moju_core.datasets import make_sequence
from moju_core.metrics import evaluate

BENCHMARKS = Path(__file__).resolve().parent
RESULTS = BENCHMARKS / "results"

#: Every method, in the order of the tables: the baselines first, MoJu last (as in Table 1).
METHODS = ("pta", "bmm", "sdg", "moju")


def sequence(name: str, n_points: int | None = None, noise: float = 0.0, seed: int = 0) -> Dataset:
    """A benchmark sequence (deterministic; generating one takes well under a second, so none
    is cached: a full-size sequence holds about 100 MB)."""
    return make_sequence(name, n_points=n_points, noise=noise, seed=seed)


def find_row(rows: list[dict], **match: Any) -> dict | None:
    """The first row whose fields equal ``match`` (e.g. ``sequence="face1", method="moju"``)."""
    for row in rows:
        if all(row[key] == value for key, value in match.items()):
            return row
    return None


def solve(
    data: Dataset,
    method: str,
    *,
    rotation_source: str = "known",
    seed: int = 0,
    keep_history: bool = False,
    visibility: np.ndarray | None = None,
    **overrides: Any,
) -> dict[str, Any]:
    """Reconstruct one sequence with one method and measure the result.

    Parameters
    ----------
    data : moju_core.datasets.Sequence
        The sequence, with its ground truth.
    method : str
        ``SolverParams.method``.
    rotation_source : {"known", "estimated"}, default "known"
        ``"known"``: the true rotations are given. ``"estimated"``: the solver's own camera
        step runs (``rotations="auto"``, the default, unless ``overrides`` name another), as a
        user without calibrated cameras would run it; the row records which estimate it
        chose and whether the loop refined it.
    seed : int, default 0
        Solver seed.
    keep_history : bool, default False
        Add the per-iteration history (lists) to the row.
    visibility : ndarray of shape (F, P), bool, optional
        The observed entries: the solver gets ``W`` with NaN at the others, and the row adds
        ``observed_fraction`` and ``e3d_occluded`` (per-frame Procrustes over the hidden
        entries; None when nothing is hidden).
    **overrides
        Further :class:`SolverParams` fields (e.g. ``subspace_dim=6``).

    Returns
    -------
    dict
        The row (see the module docstring).
    """
    known = rotation_source == "known"
    params = SolverParams(
        method=method, **({"rotations": "known"} if known else {}), seed=seed, **overrides
    )
    W = data.W
    if visibility is not None:
        W = data.W.copy()
        W[np.repeat(~visibility, 2, axis=0)] = np.nan
    # One BLAS thread, as the provenance states: with two, the BLAS rounding (and so the
    # iteration counts) and the timings depend on the other work on the machine.
    with warnings.catch_warnings(record=True) as caught, threadpool_limits(limits=1):
        warnings.simplefilter("always")
        start = time.perf_counter()
        result = reconstruct(W, params, rotations=data.rotations if known else None)
        seconds = time.perf_counter() - start
    scores = evaluate(result.shapes, data.shapes, result.rotations, data.rotations, visibility)
    row: dict[str, Any] = {
        "sequence": data.name,
        "n_frames": data.n_frames,
        "n_points": data.n_points,
        "noise": data.noise,
        "rotations": rotation_source,
        "method": method,
        "overrides": overrides,
        "e3d": scores["e3d_procrustes"],
        "e3d_global": scores["e3d_global"],
        "rotation_error_deg": scores["rotation_error_deg"],
        "seconds": seconds,
        "rotation_seconds": result.timings["rotations"],
        "initialise_seconds": result.timings["initialise"],
        "iterate_seconds": result.timings["iterate"],
        "n_iter": result.n_iter,
        "stop_reason": result.stop_reason,
        "n_groups": result.diagnostics.n_groups_used,
        "subspace_dim": result.params.subspace_dim,
        "trajectory_bases": result.params.trajectory_bases,
        "smoothness": result.params.smoothness,
        "smoothness_trials": [list(trial) for trial in result.diagnostics.smoothness_trials],
        "rotation_estimate": result.diagnostics.rotation_source,
        "rotation_window": result.diagnostics.rotation_window,
        "rotations_refined": result.diagnostics.rotations_refined,
        "n_bases": result.params.n_bases,
        "warnings": sorted({str(w.message) for w in caught}),
    }
    if visibility is not None:
        row["observed_fraction"] = float(visibility.mean())
        row["e3d_occluded"] = scores.get("e3d_occluded_procrustes")
    if keep_history:
        row["history"] = {key: values.tolist() for key, values in result.history.items()}
        row["beta2"] = result.params.beta2
        row["scale"] = result.scale
    return row


def parallel_map(function: Callable[..., Any], units: Sequence[tuple], jobs: int) -> list[Any]:
    """``[function(*unit) for unit in units]`` in ``jobs`` processes, in the order of units."""
    with ProcessPoolExecutor(jobs) as pool:
        return list(pool.map(function, *zip(*units, strict=True)))


def peak_memory_mb() -> float:
    """Peak resident memory of this process so far (MB): ``VmHWM`` of /proc/self/status, which
    belongs to the current program image, or ``ru_maxrss`` where /proc is missing."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024 * 1024 if sys.platform == "darwin" else 1024)


def describe(row: dict[str, Any]) -> str:
    """One progress line for a row."""
    extra = " ".join(
        f"{key}={value:.3g}" if isinstance(value, float) else f"{key}={value}"
        for key, value in row["overrides"].items()
    )
    return (
        f"  {row['sequence']:6s} P={row['n_points']:6,d} noise={row['noise']:.3f} "
        f"{row['rotations']:9s} {row['method']:4s} {extra:24s} e3D={row['e3d']:.4f} "
        f"{row['seconds']:7.2f} s {row['n_iter']:4d} it {row['stop_reason']}"
    )


# --- provenance ---------------------------------------------------------------------------


def _cpu_model() -> str:
    """The CPU's model name with its family and model numbers where Linux gives them: the same
    name covers several generations, whose BLAS kernels round differently."""
    try:
        fields: dict[str, str] = {}
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
        if "model name" in fields:
            numbers = [f"{k} {fields[k]}" for k in ("cpu family", "model") if k in fields]
            return fields["model name"] + (f" ({', '.join(numbers)})" if numbers else "")
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _cpu_count() -> int:
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def provenance(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Machine, library versions, the command and the time of a benchmark run."""
    import matplotlib
    import scipy
    import sklearn
    from threadpoolctl import threadpool_info

    import moju_core

    argv = list(sys.argv if argv is None else argv)
    script = Path(argv[0])
    try:
        script = script.resolve().relative_to(BENCHMARKS.parent)
    except ValueError:
        pass
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = float("nan")
    return {
        "command": shlex.join(["python", str(script), *argv[1:]]),
        "started": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "machine": {
            "cpu": _cpu_model(),
            "cores": _cpu_count(),
            "platform": platform.platform(),
            "load_average_at_start": round(load, 2),
        },
        "versions": {
            "python": platform.python_version(),
            "moju": moju_core.__version__,
            "numpy": np.__version__,
            "scipy": scipy.__version__,
            "scikit-learn": sklearn.__version__,
            "matplotlib": matplotlib.__version__,
        },
        # With the kernel set a dynamic-architecture build chose for this CPU (rounding differs).
        "blas": sorted(
            {
                f"{i['internal_api']} {i.get('version') or ''}"
                + (f" ({i['architecture']} kernels)" if i.get("architecture") else "")
                for i in threadpool_info()
            }
        ),
        "solver_threads": 1,
    }


def provenance_lines(meta: dict[str, Any]) -> list[str]:
    """The provenance as markdown lines for the head of a result file."""
    versions = ", ".join(f"{name} {version}" for name, version in meta["versions"].items())
    machine = meta["machine"]
    return [
        f"Command: `{meta['command']}` (started {meta['started']}).",
        f"Machine: {machine['cpu']}, {machine['cores']} cores, {machine['platform']}, load "
        f"average {machine['load_average_at_start']} at the start (shared machine); the solver "
        f"runs on {meta['solver_threads']} BLAS thread ({', '.join(meta['blas'])}).",
        f"Versions: {versions}.",
    ]


# --- writers -------------------------------------------------------------------------------


def write_json(path: Path, meta: dict[str, Any], **content: Any) -> Path:
    """``{"meta": ..., **content}`` as indented JSON (NaN and inf become null)."""

    def clean(value: Any) -> Any:
        if isinstance(value, float) and not np.isfinite(value):
            return None
        if isinstance(value, dict):
            return {key: clean(item) for key, item in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(item) for item in value]
        if isinstance(value, np.generic):
            return clean(value.item())
        return value

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(clean({"meta": meta, **content}), indent=1) + "\n")
    return path


def write_markdown(path: Path, title: str, meta: dict[str, Any], body: Iterable[str]) -> Path:
    """A markdown file: title, provenance, then ``body``."""
    lines = [f"# {title}", "", *provenance_lines(meta), "", *body]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines).rstrip() + "\n")
    return path


def table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> list[str]:
    """A markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return lines


def figure(*args: Any, **kwargs: Any):
    """``matplotlib.pyplot.subplots`` on the non-interactive backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(*args, **kwargs)


def save_figure(fig: Any, path: Path) -> Path:
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def mean(values: Iterable[float]) -> float:
    values = list(values)
    return float(np.mean(values)) if values else float("nan")
