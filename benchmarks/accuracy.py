"""Reconstruction accuracy (e3D, paper Eq. 17) on the synthetic sequences, in the layout of the
paper's Table 1, with known and with estimated camera rotations.

For every sequence, method and rotation source: e3D after per-frame Procrustes alignment (the
published tables' practice), after one global orthogonal alignment, the camera rotation error,
iterations and time. Estimated rotations come from the solver's default camera step
(``rotations="auto"``), run by every method as a user would run it: all methods start from the
same cameras (the step is deterministic), and the iterative methods refine them with the shapes
when the step chose the windowed estimate (pta, a single linear solve, does not). The best
rigid reconstruction (one shape for all frames, aligned to the truth) is listed per sequence as
the reference a non-rigid method has to beat.

    python benchmarks/accuracy.py                    # full size, every method
    python benchmarks/accuracy.py --quick            # 1,500 points per sequence
    python benchmarks/accuracy.py --noise 0.03       # with the paper's noise protocol

``benchmarks/run.py`` runs this as item 1 of the benchmark report.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
from harness import (
    METHODS,
    RESULTS,
    describe,
    figure,
    find_row,
    provenance,
    save_figure,
    sequence,
    solve,
    table,
    write_json,
    write_markdown,
)

from moju_core.datasets import SEQUENCE_NAMES
from moju_core.metrics import e3d, rigid_approximation

#: The paper's Table 1 (its own data: Garg et al.'s faces, Varol et al.'s paper and T-shirt),
#: for orientation only; our sequences are look-alikes, not the same data.
PUBLISHED = {
    "face1": {"pta": 0.1559, "sdg": 0.0443, "moju": 0.0404},
    "face2": {"pta": 0.1503, "sdg": 0.0381, "moju": 0.0392},
    "face3": {"pta": 0.1252, "sdg": 0.0294, "moju": 0.0280},
    "face4": {"pta": 0.1348, "sdg": 0.0309, "moju": 0.0327},
    "paper": {"pta": 0.0918, "sdg": 0.0394, "moju": 0.0338},
    "cloth": {"pta": 0.0712, "sdg": 0.0362, "moju": 0.0386},  # the paper's T-shirt
}

ROTATION_SOURCES = ("known", "estimated")


def accuracy_rows(
    names: list[str],
    methods: list[str],
    rotation_sources: list[str],
    *,
    n_points: int | None = None,
    noise: float = 0.0,
    seed: int = 0,
    keep_history: bool = False,
) -> list[dict[str, Any]]:
    """Solve every (sequence, rotation source, method) and collect the rows.

    Each row also carries ``rigid_e3d`` (the best rigid reconstruction of the sequence).
    """
    rows = []
    for name in names:
        data = sequence(name, n_points, noise, seed)
        rigid = e3d(rigid_approximation(data.shapes), data.shapes)
        print(f"{name}: F={data.n_frames} P={data.n_points} best rigid e3D={rigid:.4f}", flush=True)
        for source in rotation_sources:
            for method in methods:
                row = solve(
                    data, method, rotation_source=source, seed=seed, keep_history=keep_history
                )
                row["rigid_e3d"] = rigid
                rows.append(row)
                print(describe(row), flush=True)
    return rows


def _cell(row: dict | None, key: str = "e3d", digits: int = 4) -> str:
    if row is None:
        return "-"
    value = row[key]
    return f"{value:.{digits}f}" if np.isfinite(value) and abs(value) < 1e4 else f"{value:.3g}"


def _fmt_mean(values: Any) -> str:
    return f"{np.mean(list(values)):.4f}"


def table_lines(rows: list[dict]) -> list[str]:
    """Table 1 layout: sequences down, methods across, per rotation source; then the details."""
    names = list(dict.fromkeys(r["sequence"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    sources = list(dict.fromkeys(r["rotations"] for r in rows))
    lines: list[str] = []
    for source in sources:
        body = []
        for name in names:
            first = find_row(rows, sequence=name, rotations=source)
            if first is None:
                continue
            cells = [
                _cell(find_row(rows, sequence=name, rotations=source, method=m)) for m in methods
            ]
            present = [
                (r["e3d"], r["method"])
                for m in methods
                if (r := find_row(rows, sequence=name, rotations=source, method=m)) is not None
            ]
            best = min(present)[1]
            body.append(
                [
                    name,
                    f"{first['n_frames']} x {first['n_points']:,}",
                    f"{first['rigid_e3d']:.4f}",
                    *cells,
                    best,
                    _cell(
                        find_row(rows, sequence=name, rotations=source, method=methods[-1]),
                        "rotation_error_deg",
                        2,
                    ),
                ]
            )
        averages = [
            _fmt_mean(r["e3d"] for r in rows if (r["rotations"], r["method"]) == (source, m))
            for m in methods
        ]
        body.append(["**mean**", "", "", *averages, "", ""])
        lines += [
            f"## e3D with {source} rotations (per-frame Procrustes; lower is better)",
            "",
            *table(
                [
                    "sequence",
                    "F x P",
                    "best rigid",
                    *methods,
                    "best",
                    f"rotation error of {methods[-1]} (deg)",
                ],
                body,
            ),
            "",
        ]
    lines += [
        "## Published Table 1 (the paper's own data; for orientation, not comparable)",
        "",
        *table(
            ["sequence", "PTA", "SDG", "MoJu"],
            [
                [name, *(f"{PUBLISHED[name][m]:.4f}" for m in ("pta", "sdg", "moju"))]
                for name in names
                if name in PUBLISHED
            ],
        ),
        "",
        "## Details: time, iterations, e3D after one global alignment",
        "",
        *table(
            [
                "sequence",
                "rotations",
                "method",
                "e3D",
                "e3D (global)",
                "time (s)",
                "iterations",
                "stop",
                "groups",
                "notes",
            ],
            [
                [
                    r["sequence"],
                    r["rotations"],
                    r["method"],
                    _cell(r),
                    _cell(r, "e3d_global"),
                    f"{r['seconds']:.2f}",
                    r["n_iter"],
                    r["stop_reason"],
                    r["n_groups"],
                    _notes(r),
                ]
                for r in rows
            ],
        ),
    ]
    return lines


def _notes(row: dict) -> str:
    notes = []
    if row["method"] == "pta":
        notes.append(f"k={row['trajectory_bases']}")
    if row["method"] != "pta" and row["smoothness"]:
        notes.append(f"smoothness {row['smoothness']:g}")
    if row["rotations"] == "estimated":
        estimate = row["rotation_estimate"]
        if estimate == "windowed":
            refined = ", refined" if row["rotations_refined"] else ""
            estimate = f"windowed ({row['rotation_window']} frames{refined})"
        notes.append(f"rotations: {estimate}, K={row['n_bases']}, {row['rotation_seconds']:.1f} s")
    if row["warnings"]:
        notes.append("warned: " + "; ".join(w.split(":")[0] for w in row["warnings"]))
    return ", ".join(notes)


def write(rows: list[dict], meta: dict, out_dir: Path, stem: str, title: str) -> list[Path]:
    """Write ``stem.{json,md,png}`` (bar plot of e3D per sequence and method)."""
    paths = [
        write_json(out_dir / f"{stem}.json", meta, rows=rows),
        write_markdown(out_dir / f"{stem}.md", title, meta, table_lines(rows)),
    ]
    names = list(dict.fromkeys(r["sequence"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    sources = list(dict.fromkeys(r["rotations"] for r in rows))
    fig, axes = figure(1, len(sources), figsize=(6 * len(sources), 4), squeeze=False)
    width = 0.8 / (len(methods) + 1)
    x = np.arange(len(names))
    for ax, source in zip(axes[0], sources, strict=True):
        rigid = [find_row(rows, sequence=n)["rigid_e3d"] for n in names]
        ax.bar(x, rigid, width, label="best rigid", color="0.75")
        for i, method in enumerate(methods, start=1):
            values = [
                r["e3d"]
                if (r := find_row(rows, sequence=n, rotations=source, method=method))
                else 0
                for n in names
            ]
            ax.bar(x + i * width, values, width, label=method)
        ax.set_xticks(x + 0.4 - width / 2, names)
        ax.set_yscale("log")
        ax.set_ylabel("e3D (log scale)")
        ax.set_title(f"{source} rotations")
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0][0].legend(fontsize=8)
    paths.append(save_figure(fig, out_dir / f"{stem}.png"))
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1,500 points per sequence")
    parser.add_argument("--points", type=int, default=None, help="override the points")
    parser.add_argument("--noise", type=float, default=0.0, help="lambda_g of the noise")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sequences", nargs="+", default=list(SEQUENCE_NAMES))
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument(
        "--rotations", nargs="+", default=list(ROTATION_SOURCES), choices=ROTATION_SOURCES
    )
    parser.add_argument("--output-dir", type=Path, default=RESULTS)
    args = parser.parse_args()
    if args.quick and args.points is None:
        args.points = 1_500
    meta = provenance()
    rows = accuracy_rows(
        args.sequences,
        args.methods,
        args.rotations,
        n_points=args.points,
        noise=args.noise,
        seed=args.seed,
    )
    stem = "accuracy_quick" if args.quick else "accuracy"
    title = f"e3D on the synthetic sequences (noise lambda_g = {args.noise})"
    for path in write(rows, meta, args.output_dir, stem, title):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
