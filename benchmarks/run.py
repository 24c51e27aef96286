"""The benchmark report in one command: the paper's experiments reproduced on our data.

    python benchmarks/run.py                 # full: about an hour on 2 cores
    python benchmarks/run.py --quick         # about 4 minutes: proves the scripts still run
    python benchmarks/run.py --quick --output-dir /tmp/bench   # what CI runs

Items, each written as ``<item>.md``, ``<item>.json`` and ``<item>.png`` into the output
directory (default ``benchmarks/results``; ``benchmarks/results/quick`` with ``--quick``),
with an index ``README.md`` that lists them, checks the claims under test and records the
machine, the library versions and the command:

1. ``table1``: e3D of every method on every synthetic sequence, known and estimated rotations
   (the layout of the paper's Table 1), full size.
2. ``noise``: mean e3D over the four faces versus the noise level lambda_g (Fig. 6a).
3. ``sensitivity``: e3D versus the subspace dimension p (Fig. 6b) and the number of groups.
4. ``timing``: solve time of every method per sequence (from item 1) and versus P (Fig. 6c).
5. ``convergence``: gap and objective per iteration of a typical run (Fig. 6d).
6. ``ablations``: MoJu without the temporal prior, with the mean shape penalised, with both
   (the paper's loop), without regrouping, with the full graph, regrouping every iteration,
   without the jump (sdg) and without local groups (bmm).
7. ``nuclear_norm``: what sets the accuracy floor of the three iterative methods: the exact
   nuclear-norm minimiser versus the truth, and bmm's error versus its weight
   (``benchmarks/nuclear_norm.py``).

The sweeps (items 2, 3 and 6) use ``--sweep-points`` points per sequence (5,000 by default)
to fit the time budget; the tables say so. Every number comes from this one run.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import accuracy
import nuclear_norm
import numpy as np
import speed
from harness import (
    METHODS,
    RESULTS,
    describe,
    figure,
    find_row,
    mean,
    provenance,
    provenance_lines,
    save_figure,
    sequence,
    solve,
    table,
    write_json,
    write_markdown,
)

from moju_core.datasets import SEQUENCE_NAMES

FACES = ("face1", "face2", "face3", "face4")

#: The ablations of item 6: label -> (method, parameter overrides).
ABLATIONS: dict[str, tuple[str, dict[str, Any]]] = {
    "moju": ("moju", {}),
    "no temporal prior": ("moju", {"smoothness": 0.0}),
    "mean shape penalised": ("moju", {"free_mean_shape": False}),
    "the paper's loop": ("moju", {"smoothness": 0.0, "free_mean_shape": False}),
    "fixed groups": ("moju", {"grouping": "fixed"}),
    "full graph": ("moju", {"n_neighbors": 1000}),
    "regroup every iteration": ("moju", {"regroup_every": 1}),
    "no jump (sdg)": ("sdg", {}),
    "no local groups (bmm)": ("bmm", {}),
}


@dataclass
class Config:
    """Sizes of one benchmark mode."""

    table_points: int | None  # None: the sequences' own sizes (faces 28,880, sheets 10,000)
    sweep_points: int
    noise_levels: list[float]
    sensitivity_noise: list[float]
    subspace_dims: list[int]
    group_counts: list[int]
    timing_sequence: str
    timing_points: list[int]
    timing_repeats: int
    convergence_points: int | None
    ablation_sequences: list[str]
    ablation_noise: list[float]
    sequences: list[str] = field(default_factory=lambda: list(SEQUENCE_NAMES))

    @classmethod
    def full(cls, sweep_points: int) -> Config:
        return cls(
            table_points=None,
            sweep_points=sweep_points,
            noise_levels=[round(0.01 + 0.005 * i, 3) for i in range(10)],
            sensitivity_noise=[0.0, 0.03],
            subspace_dims=[1, 2, 3, 4, 5, 6, 8, 10],
            group_counts=[4, 8, 16, 33, 66, 133],
            timing_sequence="face3",
            timing_points=[1_000, 3_000, 10_000, 28_880],
            timing_repeats=3,
            convergence_points=None,
            ablation_sequences=list(SEQUENCE_NAMES),
            ablation_noise=[0.0, 0.03],
        )

    @classmethod
    def quick(cls, sweep_points: int) -> Config:
        return cls(
            table_points=sweep_points,
            sweep_points=sweep_points,
            noise_levels=[0.01, 0.055],
            sensitivity_noise=[0.03],
            subspace_dims=[2, 4, 6],
            group_counts=[4],
            timing_sequence="face3",
            timing_points=[sweep_points, 2 * sweep_points],
            timing_repeats=1,
            convergence_points=sweep_points,
            ablation_sequences=["face1", "face3"],
            ablation_noise=[0.03],
        )


@dataclass
class Item:
    """What one item hands to the index: its files, key lines and claim checks."""

    name: str
    title: str
    paths: list[Path]
    summary: list[str]
    claims: list[tuple[str, bool | None, str]] = field(default_factory=list)
    data: dict[str, Any] = field(default_factory=dict)


def _fmt(value: float) -> str:
    return f"{value:.4f}"


# --- 1. Table 1 ----------------------------------------------------------------------------


def table1(config: Config, meta: dict, out: Path, seed: int) -> Item:
    rows = accuracy.accuracy_rows(
        config.sequences,
        list(METHODS),
        list(accuracy.ROTATION_SOURCES),
        n_points=config.table_points,
        seed=seed,
    )
    size = "full size" if config.table_points is None else f"{config.table_points:,} points"
    paths = accuracy.write(rows, meta, out, "table1", f"Table 1 on our sequences ({size})")
    claims = []
    summary = []
    for source in accuracy.ROTATION_SOURCES:
        sub = [r for r in rows if r["rotations"] == source]
        by = {(r["sequence"], r["method"]): r for r in sub}
        means = {m: mean(r["e3d"] for r in sub if r["method"] == m) for m in METHODS}
        summary.append(
            f"{source} rotations, mean e3D over the six sequences: "
            + ", ".join(f"{m} {_fmt(v)}" for m, v in means.items())
        )
        differences = {
            name: by[name, "moju"]["e3d"] / by[name, "bmm"]["e3d"] - 1.0
            for name in config.sequences
        }
        losses = [name for name, difference in differences.items() if difference > 0]
        claims.append(
            (
                f"MoJu's e3D is at most bmm's on every sequence ({source} rotations)",
                not losses,
                f"moju above bmm on {len(losses)} of {len(differences)}; moju vs bmm: "
                + ", ".join(
                    f"{name} {by[name, 'moju']['e3d']:.5f} vs {by[name, 'bmm']['e3d']:.5f} "
                    f"({100 * difference:+.1f} %)"
                    for name, difference in differences.items()
                ),
            )
        )
    claims += target_claims(rows)
    iterations = [r["n_iter"] for r in rows if r["method"] == "moju"]
    claims.append(
        (
            "MoJu takes 120-150 iterations (the paper)",
            all(120 <= n <= 150 for n in iterations),
            f"{min(iterations)}-{max(iterations)} iterations (median {np.median(iterations):.0f})",
        )
    )
    return Item("table1", "Table 1: e3D of every method", paths, summary, claims, {"rows": rows})


def target_claims(rows: list[dict]) -> list[tuple[str, bool | None, str]]:
    """The accuracy goals for the default solver (moju): faces and sheets, known and estimated
    rotations."""

    def both(names: tuple[str, ...]) -> dict[str, tuple[dict, dict]]:
        """moju's known- and estimated-rotation rows of the sequences that have both."""
        found = {
            name: tuple(
                find_row(rows, sequence=name, rotations=source, method="moju")
                for source in ("known", "estimated")
            )
            for name in names
        }
        return {name: pair for name, pair in found.items() if None not in pair}

    claims = []
    if faces := both(FACES):
        claims.append(
            (
                "Faces: MoJu's e3D <= 0.05 with known and <= 0.08 with estimated rotations",
                all(k["e3d"] <= 0.05 and e["e3d"] <= 0.08 for k, e in faces.values()),
                ", ".join(f"{n} {k['e3d']:.4f} / {e['e3d']:.4f}" for n, (k, e) in faces.items()),
            )
        )
    if sheets := both(("paper", "cloth")):
        claims.append(
            (
                "Sheets: MoJu's e3D with estimated rotations below half the best rigid "
                "reconstruction's and below 0.05",
                all(e["e3d"] < min(0.05, 0.5 * e["rigid_e3d"]) for _, e in sheets.values()),
                ", ".join(
                    f"{n} {e['e3d']:.4f} (rigid {e['rigid_e3d']:.4f})"
                    for n, (_, e) in sheets.items()
                ),
            )
        )
    return claims


def noise(config: Config, meta: dict, out: Path, seed: int) -> Item:
    methods = ["moju", "sdg", "bmm", "pta"]
    rows = []
    for level in config.noise_levels:
        for name in FACES:
            data = sequence(name, config.sweep_points, level, seed)
            for method in methods:
                rows.append(solve(data, method, seed=seed))
                print(describe(rows[-1]), flush=True)
    averages = {
        (level, m): mean(r["e3d"] for r in rows if r["noise"] == level and r["method"] == m)
        for level in config.noise_levels
        for m in methods
    }
    body = [
        f"Known rotations, {config.sweep_points:,} points per face, noise "
        "sigma = lambda_g max|W| (one draw per level, seed "
        f"{seed}). Mean e3D over face1-face4:",
        "",
        *table(
            ["lambda_g", *methods, "moju - sdg"],
            [
                [
                    f"{level:.3f}",
                    *(_fmt(averages[level, m]) for m in methods),
                    f"{averages[level, 'moju'] - averages[level, 'sdg']:+.4f}",
                ]
                for level in config.noise_levels
            ],
        ),
        "",
        "Per face:",
        "",
        *table(
            ["lambda_g", "sequence", *methods],
            [
                [
                    f"{level:.3f}",
                    name,
                    *(
                        _fmt(
                            next(
                                r["e3d"]
                                for r in rows
                                if r["noise"] == level
                                and r["sequence"] == name
                                and r["method"] == m
                            )
                        )
                        for m in methods
                    ),
                ]
                for level in config.noise_levels
                for name in FACES
            ],
        ),
    ]
    paths = [
        write_json(out / "noise.json", meta, rows=rows),
        write_markdown(out / "noise.md", "Noise robustness (Fig. 6a)", meta, body),
    ]
    fig, ax = figure(figsize=(6, 4))
    for m in methods:
        ax.plot(config.noise_levels, [averages[lv, m] for lv in config.noise_levels], "o-", label=m)
    ax.set(xlabel="noise level lambda_g", ylabel="mean e3D over face1-4", title="Noise")
    ax.grid(True, alpha=0.3)
    ax.legend()
    paths.append(save_figure(fig, out / "noise.png"))
    high = [lv for lv in config.noise_levels if lv >= 0.03 - 1e-9]
    moju_high = mean(averages[lv, "moju"] for lv in high)
    sdg_high = mean(averages[lv, "sdg"] for lv in high)
    wins = sum(averages[lv, "moju"] < averages[lv, "sdg"] for lv in high)
    claims = [
        (
            "MoJu's mean e3D over the faces is below sdg's at lambda_g >= 0.03",
            wins == len(high),
            f"below at {wins} of {len(high)} levels; averaged over those levels moju "
            f"{_fmt(moju_high)}, sdg {_fmt(sdg_high)}",
        ),
        (
            "MoJu is more robust to noise than bmm (lambda_g >= 0.03)",
            all(averages[lv, "moju"] < averages[lv, "bmm"] for lv in high),
            f"averaged over lambda_g >= 0.03: moju {_fmt(moju_high)}, bmm "
            f"{_fmt(mean(averages[lv, 'bmm'] for lv in high))}",
        ),
    ]
    summary = [
        "mean e3D over the faces at lambda_g = "
        + "; ".join(
            f"{lv:.3f}: " + ", ".join(f"{m} {_fmt(averages[lv, m])}" for m in methods)
            for lv in (config.noise_levels[0], config.noise_levels[-1])
        )
    ]
    return Item("noise", "Noise robustness (Fig. 6a)", paths, summary, claims, {"rows": rows})


# --- 3. sensitivity ------------------------------------------------------------------------


def sensitivity(config: Config, meta: dict, out: Path, seed: int) -> Item:
    rows = []
    sweeps = [("subspace_dim", v) for v in config.subspace_dims] + [
        ("n_groups", v) for v in config.group_counts
    ]
    for level in config.sensitivity_noise:
        for name in FACES:
            data = sequence(name, config.sweep_points, level, seed)
            for key, value in sweeps:
                row = solve(data, "moju", seed=seed, **{key: value})
                row["sweep"] = key
                rows.append(row)
                print(describe(row), flush=True)

    def averages(key: str, level: float) -> dict[int, float]:
        values = config.subspace_dims if key == "subspace_dim" else config.group_counts
        return {
            v: mean(
                r["e3d"]
                for r in rows
                if r["sweep"] == key and r["noise"] == level and r["overrides"][key] == v
            )
            for v in values
        }

    def seconds(key: str, v: int) -> float:
        return mean(r["seconds"] for r in rows if r["sweep"] == key and r["overrides"][key] == v)

    body = [
        f"MoJu, known rotations, {config.sweep_points:,} points per face; mean e3D over "
        "face1-face4. Defaults: p = 4, groups = P // 150 "
        f"({config.sweep_points // 150} here).",
        "",
    ]
    for key, label in (("subspace_dim", "p"), ("n_groups", "groups")):
        values = config.subspace_dims if key == "subspace_dim" else config.group_counts
        body += [
            f"### e3D versus {label}",
            "",
            *table(
                [label, *(f"lambda_g {lv}" for lv in config.sensitivity_noise), "mean time (s)"],
                [
                    [
                        v,
                        *(_fmt(averages(key, lv)[v]) for lv in config.sensitivity_noise),
                        f"{seconds(key, v):.2f}",
                    ]
                    for v in values
                ],
            ),
            "",
        ]
    paths = [
        write_json(out / "sensitivity.json", meta, rows=rows),
        write_markdown(
            out / "sensitivity.md", "Sensitivity to p and to the number of groups", meta, body
        ),
    ]
    fig, (ax_p, ax_k) = figure(1, 2, figsize=(11, 4))
    for level in config.sensitivity_noise:
        p_means = averages("subspace_dim", level)
        k_means = averages("n_groups", level)
        ax_p.plot(list(p_means), list(p_means.values()), "o-", label=f"lambda_g {level}")
        ax_k.semilogx(list(k_means), list(k_means.values()), "o-", label=f"lambda_g {level}")
    ax_p.set(xlabel="subspace dimension p", ylabel="mean e3D over face1-4", title="p (Fig. 6b)")
    ax_k.set(xlabel="number of groups", ylabel="mean e3D over face1-4", title="groups")
    for ax in (ax_p, ax_k):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    paths.append(save_figure(fig, out / "sensitivity.png"))
    summary = []
    claims = []
    for level in config.sensitivity_noise:
        p_means = averages("subspace_dim", level)
        best_error = min(p_means.values())
        enough = min(p for p, v in p_means.items() if v <= 1.1 * best_error)
        claims.append(
            (
                f"A few singular vectors suffice: p <= 4 is within 10 % of the best p "
                f"(lambda_g {level})",
                enough <= 4,
                f"smallest p within 10 % of the best: {enough}; "
                + ", ".join(f"p={p} {_fmt(v)}" for p, v in p_means.items()),
            )
        )
        best = min(p_means, key=p_means.get)
        summary.append(
            f"lambda_g {level}: best p = {best} (e3D {_fmt(p_means[best])}); "
            + ", ".join(f"p={p} {_fmt(v)}" for p, v in p_means.items())
        )
    return Item(
        "sensitivity",
        "Sensitivity to p (Fig. 6b) and groups",
        paths,
        summary,
        claims,
        {"rows": rows},
    )


# --- 4. timing -----------------------------------------------------------------------------


def timing(config: Config, meta: dict, out: Path, seed: int, table_rows: list[dict]) -> Item:
    print(f"time versus P on {config.timing_sequence} (one subprocess per solve)", flush=True)
    vs_points = speed.speed_rows(
        [config.timing_sequence], config.timing_points, list(METHODS), config.timing_repeats
    )
    names = list(dict.fromkeys(r["sequence"] for r in table_rows))
    per_dataset = [
        [
            name,
            f"{first['n_frames']} x {first['n_points']:,}",
            *(
                f"{next(r['seconds'] for r in table_rows if r['sequence'] == name and r['rotations'] == 'known' and r['method'] == m):.2f}"  # noqa: E501
                for m in METHODS
            ),
            f"{first.get('rotation_seconds', float('nan')):.2f}",
        ]
        for name in names
        for first in [
            next(r for r in table_rows if r["sequence"] == name and r["rotations"] == "estimated")
        ]
    ]
    largest = max(config.timing_points)
    at_largest = {r["method"]: r for r in vs_points if r["n_points"] == largest}
    ratio = at_largest["moju"]["seconds"] / at_largest["sdg"]["seconds"]
    in_table = {
        name: next(
            r["seconds"]
            for r in table_rows
            if r["sequence"] == name and r["rotations"] == "known" and r["method"] == "moju"
        )
        / next(
            r["seconds"]
            for r in table_rows
            if r["sequence"] == name and r["rotations"] == "known" and r["method"] == "sdg"
        )
        for name in names
    }
    body = [
        "### Solve time per sequence (s; known rotations, from the Table 1 run)",
        "",
        *table(
            ["sequence", "F x P", *METHODS, "rotation estimation"],
            per_dataset,
        ),
        "",
        "moju / sdg time ratio per sequence (same run): "
        + ", ".join(f"{n} {v:.2f}" for n, v in in_table.items()),
        "",
        f"### Time versus P ({config.timing_sequence}, {config.timing_repeats} runs each)",
        "",
        *speed.table_lines(vs_points),
    ]
    paths = [
        write_json(out / "timing.json", meta, per_sequence=table_rows, versus_points=vs_points),
        write_markdown(out / "timing.md", "Processing time (Fig. 6c)", meta, body),
    ]
    fig, (ax_bar, ax_time, ax_mem) = figure(1, 3, figsize=(16, 4))
    width = 0.8 / len(METHODS)
    x = np.arange(len(names))
    for i, m in enumerate(METHODS):
        values = [
            next(
                r["seconds"]
                for r in table_rows
                if r["sequence"] == n and r["rotations"] == "known" and r["method"] == m
            )
            for n in names
        ]
        ax_bar.bar(x + i * width, values, width, label=m)
    ax_bar.set_xticks(x + 0.4 - width / 2, names)
    ax_bar.set_yscale("log")
    ax_bar.set(ylabel="solve time (s)", title="Per sequence (known rotations)")
    ax_bar.legend(fontsize=8)
    speed.plot(vs_points, ax_time, ax_mem)
    paths.append(save_figure(fig, out / "timing.png"))
    frames = at_largest["moju"]["n_frames"]
    claims = [
        (
            f"MoJu's solve of the {largest:,}-point, {frames}-frame face takes at most 1.5x "
            "sdg's time (same run)",
            ratio <= 1.5,
            f"moju {at_largest['moju']['seconds']:.1f} s, sdg {at_largest['sdg']['seconds']:.1f} s "
            f"(median of {config.timing_repeats}): ratio {ratio:.2f}",
        )
    ]
    summary = [
        f"at P = {largest:,} ({config.timing_sequence}): "
        + ", ".join(f"{m} {at_largest[m]['seconds']:.1f} s" for m in METHODS)
    ]
    return Item("timing", "Processing time (Fig. 6c)", paths, summary, claims, {"rows": vs_points})


# --- 5. convergence ------------------------------------------------------------------------


def convergence(config: Config, meta: dict, out: Path, seed: int) -> Item:
    data = sequence("face3", config.convergence_points, 0.0, seed)
    row = solve(data, "moju", seed=seed, keep_history=True)
    print(describe(row), flush=True)
    history = {key: np.asarray(values) for key, values in row["history"].items()}
    # The objective of Eq. 16 without the LRR term (which acts on the grouping only), in the
    # solver's scale-normalised units: 0.5 ||W - R S||_F^2 + beta2 ||S#||_*.
    entries = 2 * data.n_frames * data.n_points
    data_term = 0.5 * (history["reprojection"] / row["scale"]) ** 2 * entries
    objective = data_term + row["beta2"] * history["nuclear_norm"] / row["scale"]
    iterations = np.arange(1, row["n_iter"] + 1)
    regroups = iterations[history["relabelled"] > 0]
    body = [
        f"MoJu on face3 ({data.n_frames} frames, {data.n_points:,} points), known rotations: "
        f"{row['n_iter']} iterations, stop reason {row['stop_reason']}, e3D {_fmt(row['e3d'])}, "
        f"{row['seconds']:.1f} s. Objective = 0.5 ||W - RS||^2 + beta2 ||S#||_* in the "
        "scale-normalised units (the LRR term, which only steers the grouping, is left out). "
        "Trajectories moved at iterations " + ", ".join(str(i) for i in regroups) + ".",
        "",
        *table(
            ["iteration", "gap (S#)", "gap (C - Z)", "rho", "objective", "relabelled"],
            [
                [
                    i,
                    f"{history['gap_shape'][i - 1]:.2e}",
                    f"{history['gap_coefficients'][i - 1]:.2e}",
                    f"{history['rho'][i - 1]:.2e}",
                    f"{objective[i - 1]:.6g}",
                    f"{history['relabelled'][i - 1]:.0f}",
                ]
                for i in iterations
                if i == 1 or i % 10 == 0 or i == row["n_iter"]
            ],
        ),
    ]
    paths = [
        write_json(out / "convergence.json", meta, run=row, objective=objective.tolist()),
        write_markdown(out / "convergence.md", "A typical convergence curve (Fig. 6d)", meta, body),
    ]
    fig, (ax_gap, ax_obj) = figure(1, 2, figsize=(11, 4))
    ax_gap.semilogy(iterations, history["gap_shape"], label="||S# - f(S)||_inf")
    ax_gap.semilogy(iterations, history["gap_coefficients"], label="||C - Z||_inf")
    ax_gap.axhline(row_tol := 1e-10, color="grey", ls=":", label=f"tol {row_tol:g}")
    for i in regroups:
        ax_gap.axvline(i, color="C3", alpha=0.2)
    ax_gap.set(xlabel="iteration", ylabel="gap", title="Primal gap (red: regroupings)")
    ax_obj.plot(iterations, objective)
    ax_obj.set_yscale("log")
    ax_obj.set(xlabel="iteration", ylabel="objective", title="Objective")
    for ax in (ax_gap, ax_obj):
        ax.grid(True, which="both", alpha=0.3)
    ax_gap.legend(fontsize=8)
    paths.append(save_figure(fig, out / "convergence.png"))
    summary = [f"{row['n_iter']} iterations ({row['stop_reason']}), e3D {_fmt(row['e3d'])}"]
    return Item("convergence", "Convergence (Fig. 6d)", paths, summary, [], {"run": row})


# --- 6. ablations --------------------------------------------------------------------------


def ablations(config: Config, meta: dict, out: Path, seed: int) -> Item:
    rows = []
    for level in config.ablation_noise:
        for name in config.ablation_sequences:
            data = sequence(name, config.sweep_points, level, seed)
            for label, (method, overrides) in ABLATIONS.items():
                row = solve(data, method, seed=seed, **overrides)
                row["ablation"] = label
                rows.append(row)
                print(describe(row), flush=True)
    labels = list(ABLATIONS)

    def pick(level: float, name: str, label: str) -> dict:
        return next(
            r
            for r in rows
            if r["noise"] == level and r["sequence"] == name and r["ablation"] == label
        )

    body = [
        f"Known rotations, {config.sweep_points:,} points per sequence. 'no temporal prior': "
        "smoothness = 0; 'mean shape penalised': free_mean_shape = false (the nuclear norm of "
        "all of S#, as in the paper); 'the paper's loop': both; 'full graph': n_neighbors = "
        "1000 (every pair of groups); 'regroup every iteration': regroup_every = 1 (default "
        "10); 'fixed groups': grouping = 'fixed' (the initial k-means groups, no graph, jump, "
        "LRR or clustering).",
        "",
    ]
    means = {}
    for level in config.ablation_noise:
        means[level] = {
            label: mean(pick(level, n, label)["e3d"] for n in config.ablation_sequences)
            for label in labels
        }
        body += [
            f"### e3D at lambda_g = {level}",
            "",
            *table(
                ["sequence", *labels],
                [
                    [name, *(_fmt(pick(level, name, label)["e3d"]) for label in labels)]
                    for name in config.ablation_sequences
                ]
                + [["**mean**", *(_fmt(means[level][label]) for label in labels)]],
            ),
            "",
        ]
    body += [
        "### Mean solve time (s) over the sequences and noise levels",
        "",
        *table(
            labels,
            [
                [
                    f"{mean(r['seconds'] for r in rows if r['ablation'] == label):.2f}"
                    for label in labels
                ]
            ],
        ),
    ]
    paths = [
        write_json(out / "ablations.json", meta, rows=rows),
        write_markdown(out / "ablations.md", "Ablations of MoJu's parts", meta, body),
    ]
    fig, ax = figure(figsize=(9, 4))
    width = 0.8 / len(config.ablation_noise)
    x = np.arange(len(labels))
    for i, level in enumerate(config.ablation_noise):
        ax.bar(x + i * width, [means[level][label] for label in labels], width,
               label=f"lambda_g {level}")  # fmt: skip
    ax.set_xticks(x + 0.4 - width / 2, labels, rotation=15, fontsize=8)
    ax.set(ylabel="mean e3D", title="Ablations (mean over the sequences)")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend()
    paths.append(save_figure(fig, out / "ablations.png"))
    summary = [
        f"mean e3D at lambda_g {level}: "
        + ", ".join(f"{label} {_fmt(v)}" for label, v in means[level].items())
        for level in config.ablation_noise
    ]
    return Item("ablations", "Ablations", paths, summary, [], {"rows": rows})


# --- 7. the nuclear norm --------------------------------------------------------------------


def nuclear_norm_item(config: Config, meta: dict, out: Path, seed: int, quick: bool) -> Item:
    minimisers, weights = nuclear_norm.run(quick, seed)
    paths = nuclear_norm.write(minimisers, weights, meta, out)
    summary = [
        "exact min ||S#||_* s.t. RS = W versus the truth: "
        + "; ".join(
            f"{r['sequence']} {r['nuclear_minimiser']:.1f} < {r['nuclear_truth']:.1f}, "
            f"minimiser e3D {r['minimiser_e3d']:.3f} (bmm {r['bmm_e3d']:.4f})"
            if r["nuclear_minimiser"] < r["nuclear_truth"]
            else f"{r['sequence']}: the truth is the minimiser"
            for r in minimisers
        ),
        f"bmm on {weights[0]['sequence']} versus beta2 / sigma_1 (growth c): "
        + ", ".join(
            f"{r['beta2_relative']:g} ({r['rho_growth']:g}) {_fmt(r['e3d'])}" for r in weights
        ),
    ]
    return Item(
        "nuclear_norm",
        "What sets the accuracy floor: the nuclear norm and its continuation",
        paths,
        summary,
        [],
        {"minimisers": minimisers, "weights": weights},
    )


# --- index ---------------------------------------------------------------------------------


def write_index(items: list[Item], meta: dict, out: Path, quick: bool, seconds: float) -> Path:
    verdict = {True: "holds", False: "**does not hold**", None: "not checked"}
    lines = [
        "# Benchmark results"
        + (" (QUICK MODE: small sizes, numbers not meaningful)" if quick else ""),
        "",
        *provenance_lines(meta),
        f"Total time: {seconds / 60:.1f} min.",
        "",
        "Generated by `benchmarks/run.py`; the reading of these numbers is in "
        "`benchmarks/README.md`.",
        "",
        "## Claims under test",
        "",
        *table(
            ["claim", "verdict", "numbers"],
            [
                [claim, verdict[result], detail]
                for item in items
                for claim, result, detail in item.claims
            ],
        ),
        "",
        "## Items",
        "",
    ]
    for index, item in enumerate(items, start=1):
        files = ", ".join(f"[{p.name}]({p.name})" for p in item.paths)
        lines += [f"{index}. **{item.title}**: {files}"]
        lines += [f"   * {line}" for line in item.summary]
    path = out / "README.md"
    path.write_text("\n".join(lines) + "\n")
    write_json(
        out / "summary.json",
        meta,
        quick=quick,
        seconds=seconds,
        claims=[
            {"claim": claim, "holds": result, "numbers": detail}
            for item in items
            for claim, result, detail in item.claims
        ],
    )
    return path


ITEMS = ("table1", "noise", "sensitivity", "timing", "convergence", "ablations", "nuclear_norm")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, about 4 minutes")
    parser.add_argument(
        "--output-dir",
        type=Path,
        default=None,
        help="where to write (default benchmarks/results, or benchmarks/results/quick)",
    )
    parser.add_argument(
        "--sweep-points",
        type=int,
        default=None,
        help="points per sequence in items 2, 3 and 6 (default 5,000; 400 with --quick)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--only", nargs="+", choices=ITEMS, default=list(ITEMS), help="run some items only"
    )
    args = parser.parse_args(argv)
    sweep_points = args.sweep_points or (400 if args.quick else 5_000)
    config = Config.quick(sweep_points) if args.quick else Config.full(sweep_points)
    out = args.output_dir or (RESULTS / "quick" if args.quick else RESULTS)
    out.mkdir(parents=True, exist_ok=True)
    meta = provenance(["benchmarks/run.py", *(sys.argv[1:] if argv is None else argv)])
    meta["mode"] = "quick" if args.quick else "full"
    start = time.perf_counter()

    items: list[Item] = []
    steps: dict[str, Callable[[], Item]] = {
        "table1": lambda: table1(config, meta, out, args.seed),
        "noise": lambda: noise(config, meta, out, args.seed),
        "sensitivity": lambda: sensitivity(config, meta, out, args.seed),
        "timing": lambda: timing(config, meta, out, args.seed, table_rows),
        "convergence": lambda: convergence(config, meta, out, args.seed),
        "ablations": lambda: ablations(config, meta, out, args.seed),
        "nuclear_norm": lambda: nuclear_norm_item(config, meta, out, args.seed, args.quick),
    }
    table_rows: list[dict] = []
    if "timing" in args.only and "table1" not in args.only:
        parser.error("timing reads the per-sequence times of table1: run both")
    for name in ITEMS:
        if name not in args.only:
            continue
        tic = time.perf_counter()
        print(f"== {name}", flush=True)
        item = steps[name]()
        if name == "table1":
            table_rows = item.data["rows"]
        items.append(item)
        print(f"== {name} done in {time.perf_counter() - tic:.0f} s", flush=True)
    index = write_index(items, meta, out, args.quick, time.perf_counter() - start)
    print(f"wrote {index} ({(time.perf_counter() - start) / 60:.1f} min)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
