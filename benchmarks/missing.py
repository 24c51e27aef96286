"""Missing data: e3D against the fraction of unobserved entries, for an occluder band that
sweeps across the object together with tracks that end (structured) and for random dropout.

    python benchmarks/missing.py                  # seeds 0 and 1, ~25 min on 2 busy cores
    python benchmarks/missing.py --quick          # 300 points, seed 0 -> results/quick/
    python benchmarks/missing.py --points 5000 --closing-points 5000 --seeds 0 1 2 --jobs 1
    python benchmarks/missing.py --closing-only --dense-repeats 3 --jobs 1 \
        --output-dir benchmarks/results/missing_closing   # the closing checks, 3 timed runs each

The visibility comes from :func:`moju_core.datasets.occlusion_mask`; the solver gets ``W`` with
NaN at the hidden entries (known rotations in the sweep). Each row records e3D (per-frame
Procrustes) over all points and over the hidden entries only
(:func:`moju_core.metrics.e3d_occluded`). The sweep (``--points``, default 1,000 per sequence)
runs moju at every level, pta and bmm at a few (:data:`BASELINE_KINDS`). The closing check
(:data:`CLOSING`, a band over 20 % of the width, 10 % of the tracks lost from a random frame on,
2 % random entries) compares the missing-data solve with the complete-data solve of the same
sequence: e3D at most 1.25 x complete + 0.005, and time at most 1.3 x complete, with estimated
rotations on a dense face and a bumpy surface (``--closing-points``, default 2,000; one run
each) and with known rotations on a 41-point, 350-frame sparse face (median of ``--repeats``
interleaved runs on the first seed). All solves share a pool of ``--jobs`` processes, so the
times are those of a shared machine: compare a missing-data time only with the complete-data
time measured next to it.

Writes ``missing.json``, ``missing.md`` and ``missing.png`` into ``--output-dir`` (default
``benchmarks/results``, or ``benchmarks/results/quick`` with ``--quick``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from harness import (
    RESULTS,
    describe,
    figure,
    mean,
    provenance,
    save_figure,
    solve,
    table,
    write_json,
    write_markdown,
)

from moju_core.datasets import Sequence, make_sequence, occlusion_mask

FACES = ("face3", "face4", "face1")
SHEETS = ("paper", "cloth", "bumps-osc")
SEQUENCES = FACES + SHEETS

#: The closing configuration: band, lost tracks and dropout together.
CLOSING = {"band": 0.2, "lost": 0.1, "dropout": 0.02}
#: Occlusion kind -> the ``occlusion_mask`` settings of each level, mildest first. Structured:
#: the band hides about band / (1 + band) of the frames of each point, the lost tracks about
#: half of theirs; random: ``dropout`` of the entries; combined: the closing configuration
#: (about 21 % missing on these sequences).
LEVELS: dict[str, list[dict[str, float]]] = {
    "structured": [
        {"band": 0.1, "lost": 0.05, "dropout": 0.0},
        {"band": 0.3, "lost": 0.15, "dropout": 0.0},
        {"band": 0.7, "lost": 0.4, "dropout": 0.0},
    ],
    "random": [
        {"band": 0.0, "lost": 0.0, "dropout": 0.1},
        {"band": 0.0, "lost": 0.0, "dropout": 0.3},
        {"band": 0.0, "lost": 0.0, "dropout": 0.5},
    ],
    "combined": [CLOSING],
}
QUICK_LEVELS = {kind: levels[-2:] for kind, levels in LEVELS.items()}
KINDS = ("complete", "structured", "random", "combined")
#: The baselines run on the first seed at these points: complete, the closing configuration
#: and the heaviest level of each kind.
BASELINES = ("pta", "bmm")
BASELINE_KINDS = ("complete", "combined", "structured-max", "random-max")
#: The closing check: (sequence, n_frames or None, dense?, rotation source). The dense cases
#: run once per seed (a solve with estimated rotations takes minutes on a busy machine), the
#: sparse one ``--repeats`` times on the first seed.
CLOSING_CASES = (
    ("face3", None, True, "estimated"),
    ("bumps-osc", None, True, "estimated"),
    ("face4", 350, False, "known"),
)
SPARSE_POINTS = 41
E3D_FACTOR, E3D_SLACK, TIME_FACTOR = 1.25, 0.005, 1.3
DEFAULT_POINTS, CLOSING_POINTS, QUICK_POINTS = 1_000, 2_000, 300


def _hidden(data: Sequence, settings: dict[str, float] | None, seed: int) -> np.ndarray | None:
    return None if settings is None else occlusion_mask(data, **settings, seed=seed)


def _run(
    data: Sequence,
    method: str,
    kind: str,
    settings: dict[str, float] | None,
    seed: int,
    rotation_source: str = "known",
) -> dict[str, Any]:
    visibility = _hidden(data, settings, seed)
    row = solve(data, method, rotation_source=rotation_source, seed=seed, visibility=visibility)
    row.update(
        kind=kind,
        seed=seed,
        settings=settings or {"band": 0.0, "lost": 0.0, "dropout": 0.0},
        missing=0.0 if visibility is None else 1.0 - row["observed_fraction"],
    )
    row.setdefault("e3d_occluded", None)
    print(f"{describe(row)} [{kind}, {100 * row['missing']:.1f} % missing, seed {seed}]",
          flush=True)  # fmt: skip
    return row


def sweep_unit(
    name: str, seed: int, n_points: int, levels: dict[str, list[dict[str, float]]], baselines: bool
) -> list[dict[str, Any]]:
    """Every level of every kind on one sequence and seed (moju), and the baselines."""
    data = make_sequence(name, n_points=n_points, seed=seed)
    points: list[tuple[str, str, dict[str, float] | None]] = [("complete", "complete", None)]
    for kind, settings in levels.items():
        points += [(kind, f"{kind}-max" if s is settings[-1] else kind, s) for s in settings]
    points = [(k, "combined" if s == CLOSING else tag, s) for k, tag, s in points]
    rows = []
    for kind, tag, settings in points:
        methods = ["moju", *(BASELINES if baselines and tag in BASELINE_KINDS else ())]
        rows += [_run(data, method, kind, settings, seed) for method in methods]
    return rows


def closing_unit(
    name: str, n_frames: int | None, n_points: int, source: str, seed: int, repeats: int
) -> dict[str, Any]:
    """Complete data against the closing configuration on one sequence and seed: ``repeats``
    runs of each, interleaved, keeping the median time (and the first run's accuracy; the
    solver is deterministic for a seed)."""
    data = make_sequence(name, n_points=n_points, n_frames=n_frames, seed=seed)
    runs: dict[str, list[dict[str, Any]]] = {"complete": [], "combined": []}
    for _ in range(repeats):
        runs["complete"].append(_run(data, "moju", "complete", None, seed, source))
        runs["combined"].append(_run(data, "moju", "combined", CLOSING, seed, source))
    complete, missing = runs["complete"][0], runs["combined"][0]
    times = {k: statistics.median(r["seconds"] for r in v) for k, v in runs.items()}
    target = E3D_FACTOR * complete["e3d"] + E3D_SLACK
    return {
        "sequence": name,
        "n_frames": data.n_frames,
        "n_points": data.n_points,
        "rotations": source,
        "seed": seed,
        "missing": missing["missing"],
        "e3d_complete": complete["e3d"],
        "e3d_missing": missing["e3d"],
        "e3d_occluded": missing["e3d_occluded"],
        "e3d_target": target,
        "e3d_met": missing["e3d"] <= target,
        "runs": repeats,
        "seconds_complete": times["complete"],
        "seconds_missing": times["combined"],
        "time_ratio": times["combined"] / times["complete"],
        "time_met": times["combined"] <= TIME_FACTOR * times["complete"],
        "rotation_error_complete_deg": complete["rotation_error_deg"],
        "rotation_error_missing_deg": missing["rotation_error_deg"],
        "n_iter_complete": complete["n_iter"],
        "n_iter_missing": missing["n_iter"],
        "solves": [r for v in runs.values() for r in v],
    }


def run(
    names: list[str],
    seeds: list[int],
    n_points: int,
    closing_points: int,
    levels: dict[str, list[dict[str, float]]],
    repeats: int,
    jobs: int,
    dense_repeats: int = 1,
    closing_only: bool = False,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The sweep rows and the closing checks, in a fixed order whatever ``jobs`` is; the
    closing checks (the longest units) are submitted first."""
    closing = [
        (name, n_frames, closing_points if dense else SPARSE_POINTS, source, seed,
         dense_repeats if dense else repeats if seed == seeds[0] else 1)
        for name, n_frames, dense, source in CLOSING_CASES
        if name in names
        for seed in seeds
    ]  # fmt: skip
    sweeps = [(name, seed, n_points, levels, seed == seeds[0]) for name in names for seed in seeds]
    if closing_only:
        sweeps = []
    if jobs == 1:
        checks = [closing_unit(*args) for args in closing]
        results = [sweep_unit(*args) for args in sweeps]
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            first = [pool.submit(closing_unit, *args) for args in closing]
            second = [pool.submit(sweep_unit, *args) for args in sweeps]
            checks = [future.result() for future in first]
            results = [future.result() for future in second]
    return [row for rows in results for row in rows], checks


# --- report --------------------------------------------------------------------------------


def _fmt(value: float | None, digits: int = 4) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def _settings_text(settings: dict[str, float]) -> str:
    parts = [f"{key} {value:g}" for key, value in settings.items() if value]
    return ", ".join(parts) or "none"


def _level_key(row: dict[str, Any]) -> tuple:
    return (row["sequence"], row["kind"], tuple(sorted(row["settings"].items())))


def _average(rows: list[dict], key: str) -> float | None:
    values = [r[key] for r in rows if r.get(key) is not None]
    return mean(values) if values else None


def sweep_table(rows: list[dict]) -> list[str]:
    """One line per sequence and level: moju, pta and bmm (mean over the seeds run)."""
    order = {name: i for i, name in enumerate(SEQUENCES)}
    keys = sorted({_level_key(r) for r in rows},
                  key=lambda k: (order[k[0]], KINDS.index(k[1]), k[2]))  # fmt: skip
    body = []
    for key in keys:
        at = [r for r in rows if _level_key(r) == key]
        cells = []
        for method in ("moju", *BASELINES):
            sub = [r for r in at if r["method"] == method]
            cells += [_fmt(_average(sub, "e3d")), _fmt(_average(sub, "e3d_occluded"))]
        moju = [r for r in at if r["method"] == "moju"]
        body.append(
            [key[0], key[1], _settings_text(dict(key[2])),
             f"{100 * _average(moju, 'missing'):.1f}", *cells,
             f"{_average(moju, 'seconds'):.1f}", len(moju)]
        )  # fmt: skip
    header = ["sequence", "occlusion", "settings", "missing %", "moju e3D", "moju e3D hidden",
              "pta e3D", "pta e3D hidden", "bmm e3D", "bmm e3D hidden", "moju s",
              "seeds"]  # fmt: skip
    return table(header, body)


def closing_table(checks: list[dict]) -> list[str]:
    body = [
        [
            c["sequence"],
            f"{c['n_frames']} x {c['n_points']:,}",
            c["rotations"],
            c["seed"],
            f"{100 * c['missing']:.1f}",
            _fmt(c["e3d_complete"]),
            _fmt(c["e3d_missing"]),
            _fmt(c["e3d_target"]),
            "met" if c["e3d_met"] else "**missed**",
            _fmt(c["e3d_occluded"]),
            f"{c['seconds_complete']:.2f}",
            f"{c['seconds_missing']:.2f}",
            f"{c['time_ratio']:.2f}",
            "met" if c["time_met"] else "**missed**",
            c["runs"],
            f"{c['n_iter_complete']} / {c['n_iter_missing']}",
            f"{_fmt(c['rotation_error_complete_deg'], 2)} / "
            f"{_fmt(c['rotation_error_missing_deg'], 2)}",
        ]
        for c in checks
    ]
    header = ["sequence", "F x P", "rotations", "seed", "missing %", "e3D complete",
              "e3D missing", "target", "e3D", "e3D hidden", "s complete", "s missing",
              "time ratio", "time <= 1.3x", "runs (median)", "iterations",
              "rotation error (deg)"]  # fmt: skip
    return table(header, body)


def report_lines(rows: list[dict], checks: list[dict], meta: dict) -> list[str]:
    sizes = sorted({(r["n_frames"], r["n_points"]) for r in rows})
    return [
        "e3D (per-frame Procrustes) over all points and over the hidden entries only "
        "('hidden'), against the fraction of the F x P entries that are not observed. "
        "Visibility from `moju_core.datasets.occlusion_mask`: *structured* is a band "
        "sweeping once across the object plus tracks that end at a random frame, *random* "
        "is dropout of single entries, *combined* is the closing configuration "
        f"({_settings_text(CLOSING)}). The solver gets W with NaN at the "
        "hidden entries. "
        f"Sweep: known rotations, F x P {', '.join(f'{f} x {p:,}' for f, p in sizes)}, "
        "moju at every level, pta and bmm on the first seed at complete data, the closing "
        "configuration and the heaviest structured and random levels; mean over the seeds in "
        "the 'seeds' column.",
        "",
        "## Closing check: combined occlusion against complete data",
        "",
        f"Targets: e3D <= {E3D_FACTOR} x complete + {E3D_SLACK}; time <= {TIME_FACTOR} x "
        "complete (moju, one BLAS thread; complete and missing run next to each other in one "
        "process; with 'runs' > 1, medians of interleaved runs). Estimated rotations "
        "are the solver's own camera step on the tracks it is given. Iterations and rotation "
        "errors: complete / missing.",
        "",
        *closing_table(checks),
        "",
        "## Sweep",
        "",
        *sweep_table(rows),
    ]


def plot(rows: list[dict], path: Path) -> Path:
    """e3D against the fraction missing: faces left, sheets right; all points above, hidden
    entries below; one line per sequence (colour) and occlusion kind (line style)."""
    fig, axes = figure(2, 2, figsize=(12, 8), squeeze=False, sharex=True)
    moju = [r for r in rows if r["method"] == "moju"]
    styles = {"structured": ("-", "o"), "random": ("--", "s"), "combined": (":", "*")}
    colours = {name: f"C{i}" for i, name in enumerate(SEQUENCES)}
    for col, group in enumerate((FACES, SHEETS)):
        for row_index, key in enumerate(("e3d", "e3d_occluded")):
            ax = axes[row_index][col]
            for name in [n for n in group if any(r["sequence"] == n for r in moju)]:
                sub = [r for r in moju if r["sequence"] == name]
                complete = [r for r in sub if r["kind"] == "complete"]
                for kind, (line, marker) in styles.items():
                    levels = sorted({_level_key(r) for r in sub if r["kind"] == kind})
                    points = [[r for r in sub if _level_key(r) == k] for k in levels]
                    if key == "e3d":
                        points = [complete, *points]
                    x = [100 * _average(p, "missing") for p in points]
                    y = [_average(p, key) for p in points]
                    if points:
                        ax.plot(x, y, line, marker=marker, color=colours[name],
                                label=f"{name} {kind}")  # fmt: skip
            what = "all points" if key == "e3d" else "hidden entries"
            title = "faces" if col == 0 else "sheets"
            ax.set(yscale="log", ylabel=f"e3D, {what} (log)", title=f"{title}, e3D over {what}")
            ax.grid(True, which="both", alpha=0.3)
            if row_index == 1:
                ax.set_xlabel("missing entries (%)")
        axes[0][col].legend(fontsize=7, ncol=2)
    return save_figure(fig, path)


def write(rows: list[dict], checks: list[dict], meta: dict, out: Path) -> list[Path]:
    title = "Missing data: e3D against the fraction of unobserved entries"
    return [
        write_json(out / "missing.json", meta, closing=checks, rows=rows),
        write_markdown(out / "missing.md", title, meta, report_lines(rows, checks, meta)),
        plot(rows, out / "missing.png"),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--points", type=int, default=None,
        help=f"points per sequence in the sweep (default {DEFAULT_POINTS:,}; {QUICK_POINTS} "
        "with --quick)",
    )  # fmt: skip
    parser.add_argument(
        "--closing-points", type=int, default=None,
        help=f"points of the dense closing checks (default {CLOSING_POINTS:,}; "
        f"{QUICK_POINTS} with --quick)",
    )  # fmt: skip
    parser.add_argument("--quick", action="store_true", help="small sizes, two levels, seed 0")
    parser.add_argument(
        "--sequences", nargs="+", default=list(SEQUENCES), choices=SEQUENCES,
        help="the sequences of the sweep and of the closing checks (default: all)",
    )  # fmt: skip
    parser.add_argument("--seeds", nargs="+", type=int, default=None, help="default 0 1")
    parser.add_argument(
        "--repeats", type=int, default=None, help="timed runs of the sparse check (default 3)"
    )
    parser.add_argument(
        "--dense-repeats", type=int, default=1,
        help="timed runs of each dense closing check (default 1)",
    )  # fmt: skip
    parser.add_argument(
        "--closing-only", action="store_true",
        help="only the closing checks (use --output-dir to keep the full report)",
    )  # fmt: skip
    parser.add_argument("--jobs", type=int, default=2, help="solves in parallel processes")
    parser.add_argument("--output-dir", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.jobs < 1 or args.dense_repeats < 1 or (args.repeats is not None and args.repeats < 1):
        parser.error("--jobs, --repeats and --dense-repeats must be at least 1")
    n_points = args.points or (QUICK_POINTS if args.quick else DEFAULT_POINTS)
    closing_points = args.closing_points or (QUICK_POINTS if args.quick else CLOSING_POINTS)
    seeds = args.seeds or ([0] if args.quick else [0, 1])
    repeats = args.repeats or (1 if args.quick else 3)
    out = args.output_dir or (RESULTS / "quick" if args.quick else RESULTS)
    meta = provenance(None if argv is None else [__file__, *argv])
    start = time.perf_counter()
    levels = QUICK_LEVELS if args.quick else LEVELS
    rows, checks = run(
        args.sequences, seeds, n_points, closing_points, levels, repeats, args.jobs,
        dense_repeats=args.dense_repeats, closing_only=args.closing_only,
    )  # fmt: skip
    meta["seconds"] = time.perf_counter() - start
    for path in write(rows, checks, meta, out):
        print(f"wrote {path}")
    print(f"{len(rows)} sweep rows, {len(checks)} closing checks, {meta['seconds'] / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
