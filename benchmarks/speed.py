"""Solve time and peak memory of the methods versus the number of points P (the paper's
Fig. 6c), on the synthetic faces with known rotations.

Each solve runs in a fresh subprocess so that its peak resident memory (``ru_maxrss``) is its
own. Every configuration runs ``--repeats`` times, the methods interleaved within each repeat
(moju, sdg, ..., moju, sdg, ...) so that a busy spell of the shared machine hits all of them
alike; the median is reported.

    python benchmarks/speed.py             # moju; P = 1k, 10k, 28,880, 100k; F = 10, 99
    python benchmarks/speed.py --methods moju sdg bmm pta --sequences face3
    python benchmarks/speed.py --quick     # small sizes only, to prove it runs

``benchmarks/run.py`` runs this as item 4 of the benchmark report.

With ``--frames`` it runs the frame sweep instead (``speed_frames.{json,md,png}``): solve time
versus the number of frames F at few and at many points, MoJu's default solve with known and
with estimated rotations side by side with the plain nuclear-norm ADMM of
``reference_admm.py`` (known rotations) on the same inputs in the same run, each solve in its
own subprocess on one BLAS thread; plus the 1,102-frame, 41-point case and 1,200 against 300
frames at fixed points. It is not part of ``run.py``.

    python benchmarks/speed.py --frames                # F = 100 ... 3,000, P = 50 and 2,000
    python benchmarks/speed.py --frames --repeats 1 --timeout 600
    python benchmarks/speed.py --frames --quick        # small sizes, about a minute
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

import frame_sweep
from harness import (
    BENCHMARKS,
    METHODS,
    RESULTS,
    figure,
    provenance,
    save_figure,
    table,
    write_json,
    write_markdown,
)

#: The child process: one solve through the shared harness, plus its peak memory. The peak is
#: the child's own high-water mark (VmHWM); ``getrusage``'s ``ru_maxrss`` is not: Linux carries
#: the parent's peak over a fork and exec, so a large parent would be read as the child's peak.
CHILD = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
from harness import peak_memory_mb, sequence, solve
name, n_points, method = sys.argv[2], int(sys.argv[3]), sys.argv[4]
data = sequence(name, n_points)
baseline = peak_memory_mb()
row = solve(data, method)
row["peak_rss_mb"] = peak_memory_mb()
row["input_rss_mb"] = baseline
print(json.dumps(row))
"""


def run_one(name: str, n_points: int, method: str) -> dict[str, Any]:
    """Solve one sequence in a subprocess and return its row (with ``peak_rss_mb``)."""
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(BENCHMARKS), name, str(n_points), method],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def speed_rows(
    names: list[str], points: list[int], methods: list[str], repeats: int
) -> list[dict[str, Any]]:
    """Median time and largest peak memory of every (sequence, P, method).

    Sizes of 100,000 points or more run once: a run takes minutes and one is enough to read
    its memory.
    """
    rows = []
    for name in names:
        for n_points in points:
            runs: dict[str, list[dict]] = {method: [] for method in methods}
            for _ in range(1 if n_points >= 100_000 else repeats):
                for method in methods:
                    runs[method].append(run_one(name, n_points, method))
            for method in methods:
                done = runs[method]
                row = {
                    key: done[0][key]
                    for key in (
                        "sequence", "n_frames", "n_points", "method", "n_groups", "smoothness"
                    )
                }  # fmt: skip
                row.update(
                    runs=len(done),
                    seconds=statistics.median(r["seconds"] for r in done),
                    seconds_all=[r["seconds"] for r in done],
                    seconds_per_iteration=statistics.median(
                        r["iterate_seconds"] / r["n_iter"] for r in done
                    ),
                    n_iter=statistics.median(r["n_iter"] for r in done),
                    initialise_seconds=statistics.median(r["initialise_seconds"] for r in done),
                    peak_rss_mb=max(r["peak_rss_mb"] for r in done),
                    e3d=statistics.median(r["e3d"] for r in done),
                )
                rows.append(row)
                print(
                    f"  {name} F={row['n_frames']:3d} P={n_points:7,d} {method:4s} "
                    f"{row['seconds']:8.2f} s  {1e3 * row['seconds_per_iteration']:8.1f} ms/it  "
                    f"{row['n_iter']:.0f} it  peak {row['peak_rss_mb']:6.0f} MB  "
                    f"({', '.join(f'{s:.1f}' for s in row['seconds_all'])} s)",
                    flush=True,
                )
    return rows


def table_lines(rows: list[dict]) -> list[str]:
    return [
        "Known rotations; median over the runs (methods interleaved); peak = largest resident "
        "set size of the solving process; one BLAS thread. 'set-up' is the solver's "
        "initialisation, which includes choosing the weight of the temporal prior "
        "('smoothness') by trial solves on 400 points; 'ms / iteration' is the loop alone.",
        "",
        *table(
            [
                "sequence",
                "F",
                "P",
                "method",
                "groups",
                "smoothness",
                "iterations",
                "time (s)",
                "all runs (s)",
                "set-up (s)",
                "ms / iteration",
                "peak memory (MB)",
                "e3D",
            ],
            [
                [
                    r["sequence"],
                    r["n_frames"],
                    f"{r['n_points']:,}",
                    r["method"],
                    r["n_groups"],
                    f"{r['smoothness']:g}",
                    f"{r['n_iter']:.0f}",
                    f"{r['seconds']:.2f}",
                    ", ".join(f"{s:.2f}" for s in r["seconds_all"]),
                    f"{r['initialise_seconds']:.2f}",
                    f"{1e3 * r['seconds_per_iteration']:.1f}",
                    f"{r['peak_rss_mb']:.0f}",
                    f"{r['e3d']:.4f}",
                ]
                for r in rows
            ],
        ),
    ]


def plot(rows: list[dict], ax_time: Any, ax_mem: Any | None = None) -> None:
    """Time (and peak memory) versus P, one line per sequence and method, log-log."""
    for name in dict.fromkeys(r["sequence"] for r in rows):
        for method in dict.fromkeys(r["method"] for r in rows):
            sub = [r for r in rows if r["sequence"] == name and r["method"] == method]
            label = f"{method} ({name}, F={sub[0]['n_frames']})"
            p = [r["n_points"] for r in sub]
            ax_time.loglog(p, [r["seconds"] for r in sub], "o-", label=label)
            if ax_mem is not None:
                ax_mem.loglog(p, [r["peak_rss_mb"] for r in sub], "o-", label=label)
    ax_time.set(xlabel="points P", ylabel="solve time (s)", title="Solve time versus P")
    axes = [ax_time] if ax_mem is None else [ax_time, ax_mem]
    if ax_mem is not None:
        ax_mem.set(xlabel="points P", ylabel="peak RSS (MB)", title="Peak memory")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)


def write(rows: list[dict], meta: dict, out_dir: Path, stem: str) -> list[Path]:
    """Write ``stem.{json,md,png}``: time and peak memory versus P, per method."""
    paths = [
        write_json(out_dir / f"{stem}.json", meta, rows=rows),
        write_markdown(
            out_dir / f"{stem}.md", "Solve time and memory versus P", meta, table_lines(rows)
        ),
    ]
    fig, (ax_time, ax_mem) = figure(1, 2, figsize=(11, 4))
    plot(rows, ax_time, ax_mem)
    paths.append(save_figure(fig, out_dir / f"{stem}.png"))
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, one run each")
    parser.add_argument("--repeats", type=int, default=3, help="runs per configuration")
    parser.add_argument("--methods", nargs="+", default=["moju"], choices=METHODS)
    parser.add_argument("--sequences", nargs="+", default=["face1", "face3"])
    parser.add_argument("--points", nargs="+", type=int, default=None)
    parser.add_argument("--output-dir", type=Path, default=RESULTS)
    parser.add_argument(
        "--frames", action="store_true", help="run only the frame sweep (speed_frames.*)"
    )
    parser.add_argument(
        "--timeout",
        type=float,
        default=frame_sweep.TIMEOUT,
        help="frame sweep: seconds before a solve is stopped (larger F of it are skipped)",
    )
    args = parser.parse_args()
    if args.frames:
        frame_sweep.main(args.quick, args.repeats, args.timeout, args.output_dir)
        return
    points = args.points or ([1_000, 3_000] if args.quick else [1_000, 10_000, 28_880, 100_000])
    meta = provenance()
    rows = speed_rows(args.sequences, points, args.methods, 1 if args.quick else args.repeats)
    for path in write(rows, meta, args.output_dir, "speed_quick" if args.quick else "speed"):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
