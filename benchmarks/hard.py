"""Ablations on the hard sequences: large deformations (a waving flag, a sheet rolling up more
than a full turn, bumps growing and shrinking out of phase) under an oscillating camera and a
slow turntable, with known and with estimated rotations.

    python benchmarks/hard.py                              # 10,000 points, seeds 0 and 1
    python benchmarks/hard.py --seeds 0 1 2 3 --jobs 2     # with the validation seeds
    python benchmarks/hard.py --quick --sequences flag-osc # 1,500 points, one sequence
    python benchmarks/hard.py --sequences roll-turn --methods moju pta --merge
    python benchmarks/hard.py --sequences face1 face2 face3 face4 --merge  # the face rows

For every sequence of ``moju_core.datasets.HARD_SEQUENCE_NAMES``, seed and rotation source it
runs the methods of :data:`VARIANTS` (the default solver and its ablations, the baselines and
a rigid reconstruction) on the clean tracks, and the methods of :data:`NOISY_VARIANTS` on the
tracks with the paper's noise (``lambda_g = 0.03``, sigma = lambda_g max|W|). Each row records
e3D (per-frame Procrustes and one global alignment), the camera rotation error, iterations and
seconds, and the best rigid e3D of its sequence (one shape for all frames fitted to the truth,
the floor of any rigid reconstruction). Seeds 0 and 1 are the design seeds; rows of any other
seed are labelled ``validation`` and reported in their own tables, so that they can serve as
held-out data.

Writes ``hard.json``, ``hard.md`` and ``hard.png`` into ``--output-dir`` (default
``benchmarks/results``, or ``benchmarks/results/quick`` with ``--quick``). With ``--merge`` the
rows already in that ``hard.json`` are kept unless this run measures the same (sequence, seed,
noise, rotations, method), so a report can be assembled from partial runs. This script is not
an item of ``benchmarks/run.py``: even ``--quick`` on all six sequences takes far longer than
the minute the quick report can spare.
"""

from __future__ import annotations

import argparse
import json
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
from threadpoolctl import threadpool_limits

from moju_core.cameras.rigid import rigid_rotations
from moju_core.datasets import HARD_SEQUENCE_NAMES, Sequence, make_sequence
from moju_core.metrics import e3d, evaluate, rigid_approximation

#: Method label -> (SolverParams.method, parameter overrides); "rigid" is not a solver method
#: but the least-squares rigid shape for the cameras (see :func:`rigid_row`).
VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    "moju": ("moju", {}),
    "no groups": ("moju", {"n_groups": 1}),
    "fixed groups": ("moju", {"grouping": "fixed"}),
    "no temporal prior": ("moju", {"smoothness": 0.0}),
    "sdg": ("sdg", {}),
    "bmm": ("bmm", {}),
    "pta": ("pta", {}),
    "rigid": ("rigid", {}),
}
NOISY_VARIANTS = ("moju", "no groups", "pta")
#: The synthetic faces, run with ``--sequences`` beside the hard sequences so that the closing
#: table shows what the same solver does where the deformation is small; they have no targets.
FACE_NAMES = ("face1", "face2", "face3", "face4")
SEQUENCES = (*HARD_SEQUENCE_NAMES, *FACE_NAMES)
NOISE = 0.03
ROTATION_SOURCES = ("known", "estimated")
DESIGN_SEEDS = (0, 1)
QUICK_POINTS = 1_500
KEY_FIELDS = ("sequence", "seed", "noise", "rotations", "variant")


def split_of(seed: int) -> str:
    """``"design"`` for the seeds used while designing the solver, else ``"validation"``."""
    return "design" if seed in DESIGN_SEEDS else "validation"


def rigid_row(data: Sequence, rotation_source: str) -> dict[str, Any]:
    """The best rigid reconstruction for the cameras: Tomasi-Kanade.

    The cameras are the true ones (``"known"``) or Tomasi and Kanade's rigid factorisation
    (``"estimated"``, :func:`moju_core.cameras.rigid.rigid_rotations`); the shape is the one
    least-squares ``S`` (3, P) with ``R_f S ~ W_f`` for every frame (row-centred W), repeated
    over the frames. The row has the fields of :func:`harness.solve` that apply.
    """
    start = time.perf_counter()
    with threadpool_limits(limits=1):
        W = data.W - data.W.mean(axis=1, keepdims=True)
        known = rotation_source == "known"
        rotations = data.rotations if known else rigid_rotations(W)
        shape = np.linalg.lstsq(rotations.reshape(-1, 3), W, rcond=None)[0]
    seconds = time.perf_counter() - start
    shapes = np.broadcast_to(shape.T, data.shapes.shape)
    scores = evaluate(shapes, data.shapes, rotations, data.rotations)
    return {
        "sequence": data.name,
        "n_frames": data.n_frames,
        "n_points": data.n_points,
        "noise": data.noise,
        "rotations": rotation_source,
        "method": "rigid",
        "overrides": {},
        "e3d": scores["e3d_procrustes"],
        "e3d_global": scores["e3d_global"],
        "rotation_error_deg": scores["rotation_error_deg"],
        "seconds": seconds,
        "n_iter": 0,
        "stop_reason": "closed form",
        "rotation_estimate": rotation_source if known else "rigid",
        "warnings": [],
    }


def run_unit(
    name: str, seed: int, noise: float, n_points: int, variants: list[str], sources: list[str]
) -> list[dict[str, Any]]:
    """Every (rotation source, variant) on one sequence, seed and noise level."""
    data = make_sequence(name, n_points=n_points, noise=noise, seed=seed)
    rigid = e3d(rigid_approximation(data.shapes), data.shapes)
    rows = []
    for source in sources:
        for variant in variants:
            method, overrides = VARIANTS[variant]
            if method == "rigid":
                row = rigid_row(data, source)
            else:
                row = solve(data, method, rotation_source=source, seed=seed, **overrides)
            row.update(
                variant=variant, seed=seed, split=split_of(seed), rigid_e3d=rigid, noise=noise
            )
            rows.append(row)
            print(f"{describe(row)} [{variant}, seed {seed}]", flush=True)
    return rows


def units(
    names: list[str], seeds: list[int], variants: list[str], noise_levels: list[float]
) -> list[tuple[str, int, float, list[str]]]:
    """(sequence, seed, noise, variants) of a run: all variants clean, the noisy ones noisy."""
    plan = []
    for name in names:
        for seed in seeds:
            for level in noise_levels:
                chosen = variants if level == 0 else [v for v in variants if v in NOISY_VARIANTS]
                if chosen:
                    plan.append((name, seed, level, chosen))
    return plan


def run(
    names: list[str],
    seeds: list[int],
    variants: list[str],
    sources: list[str],
    noise_levels: list[float],
    n_points: int,
    jobs: int,
) -> list[dict[str, Any]]:
    """All rows of a run, in a fixed order whatever ``jobs`` is."""
    plan = units(names, seeds, variants, noise_levels)
    arguments = [
        (name, seed, level, n_points, chosen, sources) for name, seed, level, chosen in plan
    ]
    if jobs == 1:
        results = [run_unit(*args) for args in arguments]
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = [pool.submit(run_unit, *args) for args in arguments]
            results = [future.result() for future in futures]
    return [row for rows in results for row in rows]


def merge(old: list[dict], new: list[dict]) -> list[dict]:
    """``old`` without the rows that ``new`` measures again, then ``new``."""
    measured = {tuple(row[key] for key in KEY_FIELDS) for row in new}
    kept = [row for row in old if tuple(row[key] for key in KEY_FIELDS) not in measured]
    return kept + new


# --- report --------------------------------------------------------------------------------


def _fmt(value: float | None, digits: int = 4) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def _average(rows: list[dict], key: str = "e3d", **match: Any) -> float | None:
    values = [r[key] for r in rows if all(r[k] == v for k, v in match.items())]
    return mean(values) if values else None


def _present(rows: list[dict], key: str, order: tuple | list) -> list:
    found = {r[key] for r in rows}
    return [value for value in order if value in found]


def average_tables(rows: list[dict]) -> list[str]:
    """Per split and noise level: sequence x rotation source down, methods across."""
    lines: list[str] = []
    variants = _present(rows, "variant", list(VARIANTS))
    names = _present(rows, "sequence", SEQUENCES)
    for split in _present(rows, "split", ["design", "validation"]):
        for level in sorted({r["noise"] for r in rows}):
            sub = [r for r in rows if r["split"] == split and r["noise"] == level]
            if not sub:
                continue
            seeds = sorted({r["seed"] for r in sub})
            body = []
            for name in names:
                for source in ROTATION_SOURCES:
                    cells = [
                        _average(sub, sequence=name, rotations=source, variant=v) for v in variants
                    ]
                    if all(cell is None for cell in cells):
                        continue
                    body.append(
                        [name, source, _fmt(_average(sub, "rigid_e3d", sequence=name))]
                        + [_fmt(cell) for cell in cells]
                    )
            hard = [r for r in sub if r["sequence"] in HARD_SEQUENCE_NAMES]
            for source in ROTATION_SOURCES:
                body.append(
                    ["**mean (hard)**", source, _fmt(_average(hard, "rigid_e3d"))]
                    + [_fmt(_average(hard, rotations=source, variant=v)) for v in variants]
                )
            lines += [
                f"## e3D, {split} seeds {', '.join(map(str, seeds))}, lambda_g = {level:g} "
                "(per-frame Procrustes, mean over the seeds)",
                "",
                *table(["sequence", "rotations", "best rigid", *variants], body),
                "",
            ]
    return lines


def target_rows(rows: list[dict]) -> list[list[str]]:
    """The solver's targets on the clean hard sequences, per split, averaged over seeds:
    moju (estimated) <= half the best rigid e3D, moju (known) <= pta (known), and moju at
    least 25 % below "no groups" with known and with estimated rotations."""
    body = []
    clean = [r for r in rows if r["noise"] == 0]
    for split in _present(clean, "split", ["design", "validation"]):
        in_split = [r for r in clean if r["split"] == split]
        for name in _present(in_split, "sequence", HARD_SEQUENCE_NAMES):
            sub = [r for r in in_split if r["sequence"] == name]

            def get(source: str, variant: str, sub: list[dict] = sub) -> float | None:
                return _average(sub, rotations=source, variant=variant)

            checks = []
            rigid = _average(sub, "rigid_e3d")
            pairs = [
                ("estimated", "moju", 0.5 * rigid if rigid is not None else None),
                ("known", "moju", get("known", "pta")),
                ("known", "moju", _scaled(get("known", "no groups"), 0.75)),
                ("estimated", "moju", _scaled(get("estimated", "no groups"), 0.75)),
            ]
            for source, variant, bound in pairs:
                value = get(source, variant)
                if value is None or bound is None:
                    checks.append("-")
                else:
                    verdict = "holds" if value <= bound else "**fails**"
                    checks.append(f"{value:.4f} <= {bound:.4f}: {verdict}")
            body.append([split, name, *checks])
    return body


def _scaled(value: float | None, factor: float) -> float | None:
    return None if value is None else factor * value


def per_seed_table(rows: list[dict]) -> list[str]:
    def notes(row: dict) -> str:
        parts = []
        if row["method"] in ("moju", "sdg"):
            parts.append(f"groups {row['n_groups']}")
        if row["method"] == "pta":
            parts.append(f"k={row['trajectory_bases']}")
        if row.get("smoothness"):
            parts.append(f"smoothness {row['smoothness']:g}")
        if row["rotations"] == "estimated":
            parts.append(f"rotations: {row.get('rotation_estimate')}")
        if row["warnings"]:
            parts.append("warned: " + "; ".join(w[:60] for w in row["warnings"]))
        return ", ".join(parts)

    order = {v: i for i, v in enumerate(VARIANTS)}
    ordered = sorted(
        rows,
        key=lambda r: (
            SEQUENCES.index(r["sequence"]),
            r["noise"],
            r["seed"],
            r["rotations"] != "known",
            order[r["variant"]],
        ),
    )
    header = ["sequence", "seed", "split", "lambda_g", "rotations", "method", "e3D",
              "e3D (global)", "rotation error (deg)", "iterations", "seconds", "stop",
              "notes"]  # fmt: skip
    return table(
        header,
        [
            [
                r["sequence"],
                r["seed"],
                r["split"],
                f"{r['noise']:g}",
                r["rotations"],
                r["variant"],
                _fmt(r["e3d"]),
                _fmt(r["e3d_global"]),
                _fmt(r["rotation_error_deg"], 2),
                r["n_iter"],
                f"{r['seconds']:.2f}",
                r["stop_reason"],
                notes(r),
            ]
            for r in ordered
        ],
    )


def report_lines(rows: list[dict], meta: dict) -> list[str]:
    merged = []
    if len(meta["runs"]) > 1:
        merged = [
            "The rows were merged from these runs (a later run replaces the rows it measured "
            "again): " + "; ".join(f"`{command}`" for command in meta["runs"]) + ".",
            "",
        ]
    sizes = sorted({(r["n_frames"], r["n_points"]) for r in rows})
    variants_text = ", ".join(
        f"{label} (`{method}`{''.join(f', {k}={v}' for k, v in overrides.items())})"
        for label, (method, overrides) in VARIANTS.items()
    )
    return [
        *merged,
        "Sequences: "
        + ", ".join(_present(rows, "sequence", SEQUENCES))
        + "; F x P "
        + ", ".join(f"{f} x {p:,}" for f, p in sizes)
        + ". Methods: "
        + variants_text
        + "; rigid is the least-squares rigid shape for the true cameras (known) or for "
        "Tomasi-Kanade's (estimated). 'best rigid' is the single rigid shape fitted to the "
        "truth (the floor of any rigid reconstruction). Estimated rotations: the solver's own "
        f'camera step (`rotations="auto"`). Seeds {", ".join(map(str, DESIGN_SEEDS))} are '
        "the design seeds; other seeds are reported separately as validation.",
        "",
        *average_tables(rows),
        "## Targets (clean tracks, mean over the seeds of each split)",
        "",
        *table(
            [
                "split",
                "sequence",
                "moju (est.) <= best rigid / 2",
                "moju (known) <= pta (known)",
                "moju <= 0.75 no groups (known)",
                "moju <= 0.75 no groups (est.)",
            ],  # fmt: skip
            target_rows(rows),
        ),
        "",
        "## Every run",
        "",
        *per_seed_table(rows),
    ]


def plot(rows: list[dict], path: Path) -> Path:
    """Bars of the mean clean e3D per sequence and method, one panel per rotation source."""
    clean = [r for r in rows if r["noise"] == 0]
    names = _present(clean, "sequence", SEQUENCES)
    variants = _present(clean, "variant", list(VARIANTS))
    seeds = sorted({r["seed"] for r in clean})
    fig, axes = figure(1, 2, figsize=(14, 4.5), squeeze=False)
    width = 0.8 / (len(variants) + 1)
    x = np.arange(len(names))
    for ax, source in zip(axes[0], ROTATION_SOURCES, strict=True):
        rigid = [_average(clean, "rigid_e3d", sequence=n) or 0.0 for n in names]
        ax.bar(x, rigid, width, label="best rigid", color="0.75")
        for i, variant in enumerate(variants, start=1):
            values = [
                _average(clean, sequence=n, rotations=source, variant=variant) or 0.0 for n in names
            ]
            ax.bar(x + i * width, values, width, label=variant)
        ax.set_xticks(x + 0.4 - width / 2, names, fontsize=8)
        ax.set_yscale("log")
        ax.set(ylabel="e3D (log scale)", title=f"{source} rotations, mean over seeds {seeds}")
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7, ncol=2)
    return save_figure(fig, path)


def write(rows: list[dict], meta: dict, out: Path) -> list[Path]:
    title = "Hard sequences: large deformations, ablations, known and estimated rotations"
    return [
        write_json(out / "hard.json", meta, rows=rows),
        write_markdown(out / "hard.md", title, meta, report_lines(rows, meta)),
        plot(rows, out / "hard.png"),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=None, help="points (default 10,000)")
    parser.add_argument("--quick", action="store_true", help=f"{QUICK_POINTS:,} points")
    parser.add_argument(
        "--sequences", nargs="+", default=list(HARD_SEQUENCE_NAMES), choices=SEQUENCES
    )
    parser.add_argument("--methods", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--seeds", nargs="+", type=int, default=list(DESIGN_SEEDS))
    parser.add_argument(
        "--rotations", nargs="+", default=list(ROTATION_SOURCES), choices=ROTATION_SOURCES
    )
    parser.add_argument(
        "--noise", nargs="+", type=float, default=[0.0, NOISE],
        help=f"noise levels lambda_g (default 0 and {NOISE}; noisy runs: {NOISY_VARIANTS})",
    )  # fmt: skip
    parser.add_argument("--jobs", type=int, default=1, help="solves in parallel processes")
    parser.add_argument("--output-dir", type=Path, default=None)
    parser.add_argument(
        "--merge", action="store_true", help="keep the other rows of an existing hard.json"
    )
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error("--jobs must be at least 1")
    n_points = args.points or (QUICK_POINTS if args.quick else 10_000)
    out = args.output_dir or (RESULTS / "quick" if args.quick else RESULTS)
    meta = provenance(None if argv is None else [__file__, *argv])
    start = time.perf_counter()
    rows = run(
        args.sequences, args.seeds, args.methods, args.rotations, args.noise, n_points, args.jobs
    )
    meta["seconds"] = time.perf_counter() - start
    if args.merge and (out / "hard.json").exists():
        previous = json.loads((out / "hard.json").read_text())
        rows = merge(previous["rows"], rows)
        meta["runs"] = previous["meta"].get("runs", [previous["meta"]["command"]])
    meta["runs"] = [*meta.get("runs", []), meta["command"]]
    for path in write(rows, meta, out):
        print(f"wrote {path}")
    print(f"{len(rows)} rows, {meta['seconds'] / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
