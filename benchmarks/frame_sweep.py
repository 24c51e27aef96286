"""The frame sweep of ``speed.py --frames``: solve time versus the number of frames F.

On face4 (``moju_core.datasets.make_sequence("face4", n_frames=F, n_points=P)``, slow camera
rotation, clean tracks) three solvers run on the same inputs in the same run:

* ``moju known``: MoJu's default solve with the true rotations;
* ``moju estimated``: MoJu's default solve with its own camera step (``rotations="auto"``);
* ``admm``: the plain nuclear-norm ADMM of ``reference_admm.py`` (true rotations, fixed
  penalty, 300 iterations), the peer of the ratios.

Every solve runs in a fresh subprocess on one BLAS thread (threadpoolctl), the three
interleaved within each repeat; the median over the repeats is reported, with MoJu's own
per-stage timings (``Result.timings``: rotations, initialise, iterate). A solve that runs
longer than the timeout is stopped and recorded as such; the larger F of the same solver and P
are then skipped (the cost does not fall with F). A solve that raises is recorded with its
message. Three parts:

1. the sweep: F = 100, 300, 1,000, 3,000 at P = 50 and at P = 2,000;
2. the 1,102-frame, 41-point case (the size of a standard motion-capture sequence): targets
   moju estimated within 10x the ADMM's time, moju known within 5x, and moju known's e3D no
   worse than the ADMM's;
3. 1,200 against 300 frames at 500 and at 2,000 points, known rotations: target time ratio
   <= 5.5. The two frame counts alternate within each of at least three repeats (whatever
   ``--repeats`` says), so that a busy spell of the shared machine hits both alike.

The result files are rewritten after every configuration, so an interrupted run keeps what
it measured.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from harness import (
    BENCHMARKS,
    figure,
    provenance,
    save_figure,
    table,
    write_json,
    write_markdown,
)

SEQUENCE = "face4"
KINDS = ("moju known", "moju estimated", "admm")
FRAMES = [100, 300, 1_000, 3_000]
POINTS = [50, 2_000]
#: The motion-capture-sized case (F, P) and the frame-scaling pair
#: (F_small, F_large, point counts).
MOCAP = (1_102, 41)
SCALING = (300, 1_200, [500, 2_000])
#: Repeats of the frame-scaling pair at least (its median ratio is a target).
SCALING_REPEATS = 3
#: Seconds before a solve is stopped.
TIMEOUT = 600.0
#: Configurations with at least this many F x P entries run once whatever ``--repeats`` says.
ONE_RUN_SIZE = 1_000_000
#: Targets of the 1,102 x 41 case and of the frame scaling.
MOCAP_ESTIMATED_MAX_RATIO = 10.0
MOCAP_KNOWN_MAX_RATIO = 5.0
SCALING_MAX_RATIO = 5.5

QUICK_FRAMES = [30, 60]
QUICK_POINTS = [40]
QUICK_MOCAP = (120, 41)
QUICK_SCALING = (40, 160, [100])

#: The child process: one solve, one JSON line on stdout (errors included).
CHILD = r"""
import sys
sys.path.insert(0, sys.argv[1])
from frame_sweep import child
child(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
"""


def child(kind: str, n_frames: int, n_points: int) -> None:
    """Solve face4 of the given size with one solver and print its row as JSON."""
    from harness import solve
    from reference_admm import plain_admm
    from threadpoolctl import threadpool_limits

    from moju_core.datasets import make_sequence
    from moju_core.metrics import evaluate

    data = make_sequence(SEQUENCE, n_frames=n_frames, n_points=n_points)
    row: dict[str, Any] = {"kind": kind, "n_frames": n_frames, "n_points": n_points}
    start = time.perf_counter()
    try:
        with threadpool_limits(limits=1):
            if kind == "admm":
                result = plain_admm(data.W, data.rotations)
                seconds = time.perf_counter() - start
                scores = evaluate(result.shapes, data.shapes)
                row.update(seconds=seconds, n_iter=result.n_iter, e3d=scores["e3d_procrustes"])
            else:
                source = "known" if kind == "moju known" else "estimated"
                solved = solve(data, "moju", rotation_source=source)
                row.update(
                    {
                        key: solved[key]
                        for key in (
                            "seconds",
                            "rotation_seconds",
                            "initialise_seconds",
                            "iterate_seconds",
                            "n_iter",
                            "e3d",
                            "n_groups",
                            "smoothness",
                            "stop_reason",
                            "rotation_error_deg",
                        )
                    }
                )
        row["status"] = "ok"
    except Exception as error:  # noqa: BLE001 - the failure is the measurement
        row.update(
            status="error",
            seconds=time.perf_counter() - start,
            error=f"{type(error).__name__}: {error}",
        )
    print(json.dumps(row))


def run_one(kind: str, n_frames: int, n_points: int, timeout: float) -> dict[str, Any]:
    """One solve in a fresh subprocess; a solve past ``timeout`` seconds is stopped."""
    base = {"kind": kind, "n_frames": n_frames, "n_points": n_points}
    try:
        out = subprocess.run(
            [sys.executable, "-c", CHILD, str(BENCHMARKS), kind, str(n_frames), str(n_points)],
            check=True,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        return {**base, "status": "timeout", "seconds": timeout}
    return json.loads(out.stdout.strip().splitlines()[-1])


def median_row(done: list[dict[str, Any]]) -> dict[str, Any]:
    """The median over repeats of one (solver, F, P); the first run's status and message."""
    row = dict(done[0])
    ok = [r for r in done if r["status"] == "ok"]
    row["runs"] = len(done)
    row["seconds_all"] = [r["seconds"] for r in done]
    for key in (
        "seconds",
        "rotation_seconds",
        "initialise_seconds",
        "iterate_seconds",
        "n_iter",
        "e3d",
    ):
        values = [r[key] for r in ok if r.get(key) is not None]
        if values:
            row[key] = statistics.median(values)
    return row


def measure(
    part: str,
    sizes: list[tuple[int, int]],
    kinds: tuple[str, ...],
    repeats: int,
    timeout: float,
    rows: list[dict[str, Any]],
    save: Any,
) -> None:
    """Run every solver on every (F, P) of ``sizes`` (in order), appending to ``rows``.

    A solver that timed out at some P is skipped at the larger F of that P.
    """
    stopped: dict[tuple[str, int], int] = {}
    for n_frames, n_points in sizes:
        runs: dict[str, list[dict]] = {kind: [] for kind in kinds}
        count = 1 if n_frames * n_points >= ONE_RUN_SIZE else repeats
        for _ in range(count):
            for kind in kinds:
                if (kind, n_points) in stopped:
                    continue
                if runs[kind] and runs[kind][-1]["status"] != "ok":
                    continue
                runs[kind].append(run_one(kind, n_frames, n_points, timeout))
        for kind in kinds:
            if runs[kind]:
                row = median_row(runs[kind])
                if row["status"] == "timeout":
                    stopped[kind, n_points] = n_frames
            else:
                row = {
                    "kind": kind,
                    "n_frames": n_frames,
                    "n_points": n_points,
                    "runs": 0,
                    "status": "skipped",
                    "seconds_all": [],
                    "error": f"timed out at F = {stopped[kind, n_points]:,}",
                }
            row["part"] = part
            rows.append(row)
            print("  " + describe(row), flush=True)
        add_ratios(rows)
        save()


def measure_alternating(
    part: str,
    sizes: list[tuple[int, int]],
    kind: str,
    repeats: int,
    timeout: float,
    rows: list[dict[str, Any]],
    save: Any,
) -> None:
    """Run one solver ``repeats`` times on every (F, P) of ``sizes``, the sizes alternating
    within each repeat, and append the median rows to ``rows``. A size that failed or timed
    out is not run again."""
    runs: dict[tuple[int, int], list[dict]] = {size: [] for size in sizes}
    for _ in range(repeats):
        for size in sizes:
            if runs[size] and runs[size][-1]["status"] != "ok":
                continue
            runs[size].append(run_one(kind, *size, timeout))
    for size in sizes:
        row = median_row(runs[size])
        row["part"] = part
        rows.append(row)
        print("  " + describe(row), flush=True)
    save()


def describe(row: dict[str, Any]) -> str:
    """One progress line."""
    head = f"{row['part']:7s} F={row['n_frames']:5,d} P={row['n_points']:5,d} {row['kind']:14s}"
    if row["status"] == "ok":
        stages = ""
        if row["kind"] != "admm":
            stages = (
                f" (rotations {row['rotation_seconds']:.1f}, initialise "
                f"{row['initialise_seconds']:.1f}, iterate {row['iterate_seconds']:.1f})"
            )
        return f"{head} {row['seconds']:8.2f} s{stages} {row['n_iter']:.0f} it e3D {row['e3d']:.4f}"
    if row["status"] == "timeout":
        return f"{head} stopped after {row['seconds']:.0f} s"
    return f"{head} {row['status']}: {row.get('error', '')}"


def add_ratios(rows: list[dict[str, Any]]) -> None:
    """``ratio_to_admm`` of every MoJu row whose ADMM row (same part, F, P) finished or was
    stopped, when one of the two finished.

    For a MoJu solve that was stopped the ratio is a lower bound (``ratio_is_lower_bound``),
    against an ADMM that was stopped an upper bound (``ratio_is_upper_bound``).
    """
    admm = {
        (r["part"], r["n_frames"], r["n_points"]): r
        for r in rows
        if r["kind"] == "admm" and r["status"] in ("ok", "timeout")
    }
    for row in rows:
        peer = admm.get((row["part"], row["n_frames"], row["n_points"]))
        if row["kind"] == "admm" or peer is None or row["status"] not in ("ok", "timeout"):
            continue
        if row["status"] == peer["status"] == "timeout":
            continue
        row["ratio_to_admm"] = row["seconds"] / peer["seconds"]
        row["ratio_is_lower_bound"] = row["status"] == "timeout"
        row["ratio_is_upper_bound"] = peer["status"] == "timeout"


def _seconds(row: dict | None, key: str = "seconds") -> str:
    if row is None:
        return "-"
    if row["status"] == "timeout":
        return f"> {row['seconds']:.0f} (stopped)" if key == "seconds" else "-"
    if row["status"] != "ok":
        return row["status"]
    value = row.get(key)
    return "-" if value is None else f"{value:.2f}"


def _ratio(row: dict | None) -> str:
    if row is None or "ratio_to_admm" not in row:
        return "-"
    bound = "<= " if row.get("ratio_is_upper_bound") else ""
    bound = ">= " if row["ratio_is_lower_bound"] else bound
    return bound + f"{row['ratio_to_admm']:.1f}"


def table_lines(rows: list[dict[str, Any]], part: str) -> list[str]:
    """The rows of one part as a markdown table."""
    return table(
        [
            "F",
            "P",
            "solver",
            "time (s)",
            "runs (s)",
            "rotations (s)",
            "initialise (s)",
            "iterate (s)",
            "iterations",
            "groups",
            "smoothness",
            "e3D",
            "x ADMM",
            "note",
        ],
        [
            [
                f"{r['n_frames']:,}",
                f"{r['n_points']:,}",
                r["kind"],
                _seconds(r),
                ", ".join(f"{s:.1f}" for s in r["seconds_all"]),
                _seconds(r, "rotation_seconds"),
                _seconds(r, "initialise_seconds"),
                _seconds(r, "iterate_seconds"),
                f"{r['n_iter']:.0f}" if r["status"] == "ok" else "-",
                r.get("n_groups", "-"),
                f"{r['smoothness']:g}" if r.get("smoothness") is not None else "-",
                f"{r['e3d']:.4f}" if r["status"] == "ok" else "-",
                _ratio(r),
                r.get("error", ""),
            ]
            for r in rows
            if r["part"] == part
        ],
    )


def find(rows: list[dict], part: str, kind: str, n_frames: int) -> dict | None:
    return next(
        (r for r in rows if r["part"] == part and r["kind"] == kind and r["n_frames"] == n_frames),
        None,
    )


def find_scaling(rows: list[dict], n_frames: int, n_points: int) -> dict | None:
    return next(
        (
            r
            for r in rows
            if r["part"] == "scaling" and r["n_frames"] == n_frames and r["n_points"] == n_points
        ),
        None,
    )


def targets(rows: list[dict], mocap: tuple[int, int], scaling: tuple) -> list:
    """The targets as (claim, verdict, numbers); verdict None when not measured."""
    out = []
    admm = find(rows, "mocap", "admm", mocap[0])
    for kind, limit in (
        ("moju estimated", MOCAP_ESTIMATED_MAX_RATIO),
        ("moju known", MOCAP_KNOWN_MAX_RATIO),
    ):
        row = find(rows, "mocap", kind, mocap[0])
        claim = f"{mocap[0]:,} x {mocap[1]}: {kind} within {limit:g}x the ADMM's time"
        if row is None or "ratio_to_admm" not in row:
            verdict = False if row is not None and row["status"] == "error" else None
            out.append((claim, verdict, describe(row) if row else "not run"))
            continue
        within = row["ratio_to_admm"] <= limit
        # A lower bound (MoJu stopped) decides only a miss; an upper bound only a pass.
        verdict: bool | None = within
        if row["ratio_is_lower_bound"] and within or row.get("ratio_is_upper_bound") and not within:
            verdict = None
        out.append(
            (
                claim,
                verdict,
                f"{_seconds(row)} s against {_seconds(admm)} s: {_ratio(row)}x",
            )
        )
    known = find(rows, "mocap", "moju known", mocap[0])
    claim = f"{mocap[0]:,} x {mocap[1]}: moju known's e3D no worse than the ADMM's"
    if known is not None and admm is not None and known["status"] == admm["status"] == "ok":
        out.append(
            (claim, known["e3d"] <= admm["e3d"], f"{known['e3d']:.4f} against {admm['e3d']:.4f}")
        )
    else:
        out.append(
            (
                claim,
                False if known and known["status"] == "error" else None,
                describe(known) if known else "not run",
            )
        )
    for n_points in scaling[2]:
        out.append(scaling_target(rows, scaling[0], scaling[1], n_points))
    return out


def scaling_target(rows: list[dict], f_small: int, f_large: int, n_points: int) -> tuple:
    """The frame-scaling target at P points as (claim, verdict, numbers)."""
    small, large = (find_scaling(rows, f, n_points) for f in (f_small, f_large))
    claim = (
        f"{f_large:,} frames at most {SCALING_MAX_RATIO:g}x the time of {f_small:,} "
        f"({n_points:,} points)"
    )
    if small is None or large is None or small["status"] != "ok":
        return claim, None, describe(small) if small else "not run"
    ratio = large["seconds"] / small["seconds"]
    if large["status"] == "ok":
        numbers = f"{large['seconds']:.1f} s against {small['seconds']:.1f} s: {ratio:.1f}x"
        return claim, ratio <= SCALING_MAX_RATIO, numbers
    if large["status"] == "timeout":
        numbers = (
            f"stopped after {large['seconds']:.0f} s against {small['seconds']:.1f} s: "
            f">= {ratio:.1f}x"
        )
        return claim, False, numbers
    return claim, False, describe(large)


def write(rows: list[dict], meta: dict, out_dir: Path, stem: str, config: dict) -> list[Path]:
    """Write ``stem.{json,md,png}``."""
    verdict = {True: "met", False: "**missed**", None: "not measured"}
    checks = targets(rows, config["mocap"], config["scaling"])
    body = [
        f"{SEQUENCE} (`make_sequence('{SEQUENCE}', n_frames=F, n_points=P)`), clean tracks. "
        "'moju known' / 'moju estimated': the default solve with the true rotations / with "
        "its own camera step; 'admm': the plain nuclear-norm ADMM of "
        "`benchmarks/reference_admm.py` (true rotations, fixed penalty, 300 iterations, full "
        "SVD). Each solve in its own subprocess on one BLAS thread, the three interleaved; "
        f"median of the runs (configurations of at least {ONE_RUN_SIZE:,} F x P entries run "
        f"once). A solve is stopped after {config['timeout']:.0f} s, and the larger F of "
        "that solver and P are then skipped. 'rotations', 'initialise' and 'iterate' are "
        "MoJu's own stage timings (`Result.timings`; 'initialise' includes choosing the "
        "temporal prior's weight by trial solves). 'x ADMM': time over the ADMM's on the same "
        "input ('>=' when MoJu was stopped, '<=' when the ADMM was).",
        "",
        "## Targets",
        "",
        *table(
            ["target", "verdict", "numbers"],
            [[claim, verdict[v], detail] for claim, v, detail in checks],
        ),
        "",
        f"## Frame sweep (F = {', '.join(f'{f:,}' for f in config['frames'])}; "
        f"P = {', '.join(f'{p:,}' for p in config['points'])})",
        "",
        *table_lines(rows, "sweep"),
        "",
        f"## {config['mocap'][0]:,} frames x {config['mocap'][1]} points",
        "",
        *table_lines(rows, "mocap"),
        "",
        f"## {config['scaling'][1]:,} against {config['scaling'][0]:,} frames at "
        f"{' and '.join(f'{p:,}' for p in config['scaling'][2])} points (known rotations)",
        "",
        f"Median of {config['scaling_repeats']} runs each, the frame counts alternating "
        "within each repeat.",
        "",
        *table_lines(rows, "scaling"),
    ]
    paths = [
        write_json(
            out_dir / f"{stem}.json",
            meta,
            config=config,
            rows=rows,
            targets=[{"target": c, "met": v, "numbers": d} for c, v, d in checks],
        ),
        write_markdown(
            out_dir / f"{stem}.md", "Solve time versus the number of frames", meta, body
        ),
    ]
    paths.append(plot(rows, out_dir / f"{stem}.png"))
    return paths


def plot(rows: list[dict], path: Path) -> Path:
    """Time versus F (log-log, per P and solver; open marks: stopped) and the ratio to ADMM."""
    fig, (ax_time, ax_ratio) = figure(1, 2, figsize=(12, 4.5))
    sweep = [r for r in rows if r["part"] == "sweep"]
    styles = {"moju known": "o-", "moju estimated": "s--", "admm": "^:"}
    for i, n_points in enumerate(dict.fromkeys(r["n_points"] for r in sweep)):
        for kind in KINDS:
            sub = [r for r in sweep if r["n_points"] == n_points and r["kind"] == kind]
            done = [r for r in sub if r["status"] == "ok"]
            stopped = [r for r in sub if r["status"] == "timeout"]
            color = f"C{2 * i + (kind == 'admm')}" if kind != "moju estimated" else f"C{4 + i}"
            if done:
                ax_time.loglog(
                    [r["n_frames"] for r in done],
                    [r["seconds"] for r in done],
                    styles[kind],
                    color=color,
                    label=f"{kind}, P={n_points:,}",
                )
            if stopped:
                ax_time.loglog(
                    [r["n_frames"] for r in stopped],
                    [r["seconds"] for r in stopped],
                    "x",
                    color=color,
                    ms=10,
                )
            ratios = [r for r in sub if "ratio_to_admm" in r]
            if ratios:
                ax_ratio.loglog(
                    [r["n_frames"] for r in ratios],
                    [r["ratio_to_admm"] for r in ratios],
                    styles[kind],
                    color=color,
                    label=f"{kind}, P={n_points:,}",
                )
    ax_time.set(
        xlabel="frames F",
        ylabel="solve time (s)",
        title="Solve time versus F (x: stopped at the timeout)",
    )
    ax_ratio.axhline(1.0, color="grey", lw=0.8)
    ax_ratio.set(
        xlabel="frames F",
        ylabel="time / plain ADMM's",
        title="Ratio to the plain ADMM (same input, same run)",
    )
    for ax in (ax_time, ax_ratio):
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    return save_figure(fig, path)


def main(quick: bool, repeats: int, timeout: float, out_dir: Path) -> None:
    """Run the three parts and write ``speed_frames[_quick].{json,md,png}``."""
    frames, points = (QUICK_FRAMES, QUICK_POINTS) if quick else (FRAMES, POINTS)
    mocap, scaling = (QUICK_MOCAP, QUICK_SCALING) if quick else (MOCAP, SCALING)
    repeats = 1 if quick else repeats
    config = {
        "sequence": SEQUENCE,
        "frames": frames,
        "points": points,
        "mocap": mocap,
        "scaling": scaling,
        "scaling_repeats": max(repeats, SCALING_REPEATS),
        "repeats": repeats,
        "timeout": timeout,
    }
    meta = provenance()
    stem = "speed_frames_quick" if quick else "speed_frames"
    rows: list[dict] = []

    def save() -> None:
        write(rows, meta, out_dir, stem, config)

    measure("mocap", [mocap], KINDS, repeats, timeout, rows, save)
    for n_points in scaling[2]:
        sizes = [(scaling[0], n_points), (scaling[1], n_points)]
        measure_alternating(
            "scaling", sizes, "moju known", config["scaling_repeats"], timeout, rows, save
        )
    for n_points in points:
        measure("sweep", [(f, n_points) for f in frames], KINDS, repeats, timeout, rows, save)
    for path in write(rows, meta, out_dir, stem, config):
        print(f"wrote {path}")
