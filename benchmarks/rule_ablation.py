"""Rule ablation: e3D of the solver with each data-derived rule, and with the rule switched off.

    python benchmarks/rule_ablation.py                     # every rule, seeds 0-3 and 301-306
    python benchmarks/rule_ablation.py --quick             # one design and one held-out seed
    python benchmarks/rule_ablation.py --rules flung-factor signal-fit --seeds 301 302

Each rule of :data:`RULES` names the constant or function that carries it, a neutral setting
(the rule switched off: a module attribute replaced for the solve) and the small sequences it
concerns. Every (case, seed) is solved once with the code as it is and once per rule with the
neutral setting; the tables give e3D with and without the rule. Seeds: the design seeds the
notebook (``benchmarks/notes/2026-12-06-solver-measurements.md``) set the rules on, and
held-out seeds it never mentions (:data:`HELD_OUT_SEEDS`).

The criterion: a rule is kept when, on the held-out seeds, its mean e3D over the cases it
concerns is lower than without it by more than the seed-to-seed noise (the standard error of
the mean paired difference), or when it prevents a failure (e3D above 1, or a solve that
raises) on some held-out seed. A rule that changes no held-out solve (the same shapes with it
and without) has shown no benefit; it stays only where a test reproduces the failure it
guards against.

Rules removed after their measurement (``depth-prior-gate``, ``group-fill-hidden-weight``,
``gap-significance``) are no longer listed; their rows are in ``benchmarks/results/rules/`` and
``benchmarks/notes/2026-12-06-rule-ablation.md``.

Writes ``rules.json`` and ``rules.md`` into ``--output-dir`` (default
``benchmarks/results/rules``).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import math
import statistics
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from harness import RESULTS, provenance, table, write_json, write_markdown

from moju_core import SolverParams, defaults, reconstruct, solve_plan, solver
from moju_core.completion import exact_model, gaps, missing, neighbours, window_subspace
from moju_core.datasets import make_sequence, occlusion_mask
from moju_core.loop import loop_state
from moju_core.metrics import e3d
from moju_core.priors import smoothness

#: Seeds the notebook measured the rules on (most rules were set on seeds 0-3).
DESIGN_SEEDS = (0, 1, 2, 3)
#: Seeds the notebook never mentions.
HELD_OUT_SEEDS = (301, 302, 303, 304, 305, 306)


@dataclass(frozen=True)
class Case:
    """A small solve: sequence, frames, points, noise, occlusion (None or occlusion_mask
    settings), known rotations, and a prior weight given by the caller (None: chosen)."""

    sequence: str
    frames: int
    points: int
    noise: float = 0.0
    occlusion: tuple[tuple[str, float], ...] | None = None
    known: bool = True
    smoothness: float | None = None

    @property
    def label(self) -> str:
        parts = [f"{self.sequence} {self.frames}x{self.points}"]
        if self.noise:
            parts.append(f"noise {self.noise:g}")
        if self.occlusion:
            parts.append("+".join(f"{k} {v:g}" for k, v in self.occlusion if v))
        parts.append("known" if self.known else "estimated")
        if self.smoothness is not None:
            parts.append(f"weight {self.smoothness:g}")
        return ", ".join(parts)


CLOSING = (("band", 0.2), ("lost", 0.1), ("dropout", 0.02))
LOST = (("band", 0.0), ("lost", 0.1), ("dropout", 0.0))

# The benchmark's own frame counts (the rules depend on how far and how often the camera
# turns), with a few hundred points.
FACE3 = Case("face3", 99, 300)
FACE4 = Case("face4", 99, 300)
BUMPS = Case("bumps-osc", 60, 300)
FLAG = Case("flag-osc", 60, 300)
FACE1 = Case("face1", 10, 300)
FACE2 = Case("face2", 10, 300)
FACE3_30 = Case("face3", 30, 400)
PAPER_EST = Case("paper", 60, 300, known=False)
FACE3_CLOSING = Case("face3", 99, 300, occlusion=CLOSING)
MARKERS_CLOSING = Case("face4", 350, 41, occlusion=CLOSING)
BODY_CLOSING = Case("body-osc", 350, 41, occlusion=CLOSING)
DROPOUT = (("band", 0.0), ("lost", 0.0), ("dropout", 0.1))
FACE3_CLOSING_EST = Case("face3", 99, 300, occlusion=CLOSING, known=False)
PAPER_CLOSING_EST = Case("paper", 60, 300, occlusion=CLOSING, known=False)


@dataclass(frozen=True)
class Rule:
    """A data-derived rule: where it lives, its neutral setting, the cases it concerns."""

    name: str
    where: str
    neutral: str
    patches: tuple[tuple[Any, str, Any], ...]
    cases: tuple[Case, ...]


def _one_value(rotations: np.ndarray, signal_rank: int = 0) -> int:
    return 1


def _never(*args: Any, **kwargs: Any) -> bool:
    return False


def _fixed_weight(*args: Any, **kwargs: Any) -> smoothness.SmoothnessChoice:
    return smoothness.SmoothnessChoice(defaults.MIN_DEPTH_PRIOR, defaults.MIN_DEPTH_PRIOR)


RULES: tuple[Rule, ...] = (
    Rule(
        "exact-data-noise",
        "defaults.EXACT_DATA_NOISE (solve_plan.exact_data, defaults.resolve)",
        "0: every track counts as noisy (soft fit, mean shape only unshrunk)",
        ((defaults, "EXACT_DATA_NOISE", 0.0), (solve_plan, "EXACT_DATA_NOISE", 0.0)),
        (FACE3, BUMPS, PAPER_EST, FACE3_CLOSING),
    ),
    Rule(
        "unshrunk-values",
        "defaults.unshrunk_values (MAX_UNSHRUNK_VALUES, MIN_DEPTH_BASIS)",
        "1: only the mean shape is left unshrunk",
        ((defaults, "unshrunk_values", _one_value),),
        (FACE3, FACE4, BUMPS, FLAG),
    ),
    Rule(
        "unshrink-after",
        "defaults.UNSHRINK_AFTER (loop_state)",
        "0: the unshrunk values are left out from the first iteration",
        ((loop_state, "UNSHRINK_AFTER", 0),),
        (FACE3, FACE4, BUMPS, FLAG, PAPER_EST),
    ),
    Rule(
        "exact-fit-allowance",
        "priors.smoothness.EXACT_FIT_ALLOWANCE",
        "-1: an exact fit takes the soft rule's weight",
        ((smoothness, "EXACT_FIT_ALLOWANCE", -1.0),),
        (BUMPS, FLAG, FACE1, FACE3_30),
    ),
    Rule(
        "smoothness-choice",
        "priors.smoothness.choose_smoothness (DEFORMATION_ALLOWANCE, SMOOTHNESS_GRID)",
        "a fixed weight MIN_DEPTH_PRIOR = 10, no trial solves",
        ((solver, "choose_smoothness", _fixed_weight),),
        (FACE1, FACE2, FACE3, BUMPS, Case("cloth", 60, 300, noise=0.01)),
    ),
    Rule(
        "signal-fit",
        "solve_plan.tries_signal_fit",
        "never: noisy tracks are always fitted softly",
        ((solve_plan, "tries_signal_fit", _never),),
        (
            Case("face3", 99, 300, noise=0.01),
            Case("paper", 60, 300, noise=0.01),
            Case("bumps-osc", 60, 300, noise=0.01),
        ),
    ),
    Rule(
        "flung-factor",
        "solver.FLUNG_FACTOR",
        "inf: a masked exact fit is never abandoned",
        ((solver, "FLUNG_FACTOR", math.inf),),
        (Case("body-osc", 350, 41, occlusion=LOST), Case("face3", 99, 300, occlusion=LOST)),
    ),
    Rule(
        "trusted-leverage",
        "completion.missing.TRUSTED_LEVERAGE",
        "inf: every hidden entry is trusted",
        ((missing, "TRUSTED_LEVERAGE", math.inf),),
        (
            FACE3_CLOSING,
            Case("bumps-osc", 60, 300, occlusion=CLOSING),
            MARKERS_CLOSING,
        ),
    ),
    Rule(
        "max-unexplained",
        "completion.missing.MAX_UNEXPLAINED",
        "inf: an approximate completion is trusted like any other",
        ((missing, "MAX_UNEXPLAINED", math.inf),),
        (BODY_CLOSING, Case("body-turn", 350, 41, occlusion=CLOSING), MARKERS_CLOSING),
    ),
    Rule(
        "overfit-patience",
        "completion.missing.OVERFIT_PATIENCE",
        "1: the rank search stops at the first rank with twice the best held-out error",
        ((missing, "OVERFIT_PATIENCE", 1),),
        (FACE3_CLOSING_EST, PAPER_CLOSING_EST, Case("bumps-osc", 60, 300, occlusion=CLOSING)),
    ),
    Rule(
        "hold-out-runs",
        "completion.missing.HOLD_OUT_RUN_POINTS (HOLD_OUT_RUN_LENGTH)",
        "0: the rank is chosen on random held-out entries only",
        ((missing, "HOLD_OUT_RUN_POINTS", 0.0),),
        (FACE3_CLOSING_EST, PAPER_CLOSING_EST, MARKERS_CLOSING),
    ),
    Rule(
        "noise-windows",
        "completion.missing.NOISE_WINDOWS",
        "(10,): no 5-frame blocks when no 10-frame block qualifies",
        ((missing, "NOISE_WINDOWS", (10,)),),
        (Case("body-osc", 350, 41, occlusion=DROPOUT), Case("face1", 10, 300, occlusion=CLOSING)),
    ),
    Rule(
        "extra-directions",
        "completion.window_subspace.EXTRA_DIRECTIONS",
        "0: the exact model tries no directions beyond the windows' largest rank",
        ((window_subspace, "EXTRA_DIRECTIONS", 0),),
        (FACE3_CLOSING, FACE3_CLOSING_EST, Case("cloth", 60, 300, occlusion=CLOSING)),
    ),
    Rule(
        "well-seen",
        "completion.missing.WELL_SEEN (exact model, neighbours, camera points)",
        "0: every point seen in any frame counts as well seen",
        ((missing, "WELL_SEEN", 0.0),),
        (FACE3_CLOSING, PAPER_CLOSING_EST, MARKERS_CLOSING),
    ),
    Rule(
        "neighbours",
        "completion.neighbours.NEIGHBOURS",
        "1: an undetermined entry takes the values of its single nearest neighbour",
        ((neighbours, "NEIGHBOURS", 1),),
        (
            Case("face3", 99, 300, occlusion=LOST),
            FACE3_CLOSING,
            Case("body-osc", 350, 41, occlusion=LOST),
        ),
    ),
    Rule(
        "gap-decays",
        "completion.gaps.DECAYS (gaps.CANDIDATES)",
        "(0,): hidden entries are never moved towards the tracks",
        ((gaps, "DECAYS", (0.0,)), (gaps, "CANDIDATES", (gaps.GapFill(),))),
        (
            Case("face3", 99, 300, noise=0.01, occlusion=CLOSING),
            Case("paper", 60, 300, occlusion=CLOSING),
            Case("face4", 350, 41, noise=0.01, occlusion=CLOSING),
            Case("body-osc", 350, 41, occlusion=DROPOUT),
        ),
    ),
    Rule(
        "window-lengths",
        "completion.window_subspace.WINDOW_LENGTHS",
        "(12,): one window length, the shortest",
        ((window_subspace, "WINDOW_LENGTHS", (12,)),),
        (FACE3_CLOSING, FACE3_CLOSING_EST, Case("cloth", 60, 300, occlusion=CLOSING)),
    ),
    Rule(
        "low-rank-fraction",
        "completion.window_subspace.LOW_RANK_FRACTION",
        "1: every window's block counts as showing a low rank",
        ((window_subspace, "LOW_RANK_FRACTION", 1.0),),
        (
            FACE3_CLOSING,
            FACE3_CLOSING_EST,
            Case("cloth", 60, 300, occlusion=CLOSING),
            Case("paper", 60, 300, occlusion=CLOSING),
            Case("bumps-osc", 60, 300, occlusion=CLOSING),
            Case("flag-osc", 60, 300, occlusion=CLOSING),
        ),
    ),
    Rule(
        "spare-gap",
        "completion.exact_model.SPARE_GAP",
        "0: the exact model's spare directions are never cut",
        ((exact_model, "SPARE_GAP", 0.0),),
        (FACE3_CLOSING, FACE3_CLOSING_EST, Case("cloth", 60, 300, occlusion=CLOSING)),
    ),
    Rule(
        "pta-max-condition",
        "defaults.PTA_MAX_CONDITION (trajectory_basis_size, unshrunk_values)",
        "inf: any basis size counts as well conditioned",
        ((defaults, "PTA_MAX_CONDITION", math.inf),),
        (FACE3, FACE4, BUMPS, FLAG),
    ),
)


@contextlib.contextmanager
def patched(patches: tuple[tuple[Any, str, Any], ...]) -> Iterator[None]:
    """Replace module attributes for the duration of a solve."""
    saved = [(module, name, getattr(module, name)) for module, name, _ in patches]
    try:
        for module, name, value in patches:
            setattr(module, name, value)
        yield
    finally:
        for module, name, value in saved:
            setattr(module, name, value)


def run_case(case: Case, seed: int) -> dict[str, Any]:
    """Solve one case (default parameters, solver seed 0): e3D, iterations, time, error."""
    data = make_sequence(
        case.sequence, n_frames=case.frames, n_points=case.points, seed=seed, noise=case.noise
    )
    W, visibility = data.W, None
    if case.occlusion is not None:
        visibility = occlusion_mask(data, seed=seed, **dict(case.occlusion))
        W = np.where(np.repeat(visibility, 2, axis=0), W, np.nan)
    start = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = reconstruct(
                W,
                SolverParams(seed=0, smoothness=case.smoothness),
                rotations=data.rotations if case.known else None,
                visibility=visibility,
                threads=1,
            )
    except Exception as error:  # noqa: BLE001 - a failure is a measurement here
        return {"e3d": math.inf, "error": repr(error), "seconds": time.perf_counter() - start}
    return {
        "e3d": float(e3d(result.shapes, data.shapes)),
        "digest": hashlib.sha256(np.ascontiguousarray(result.shapes).tobytes()).hexdigest()[:16],
        "n_iter": int(result.n_iter),
        "seconds": time.perf_counter() - start,
    }


def measure(rules: list[Rule], seeds: list[int], log: Callable[[str], None]) -> list[dict]:
    """Every rule's cases on every seed, with the rule and without."""
    baseline: dict[tuple[Case, int], dict] = {}
    rows = []
    for rule in rules:
        for case in rule.cases:
            for seed in seeds:
                if (case, seed) not in baseline:
                    baseline[(case, seed)] = run_case(case, seed)
                with patched(rule.patches):
                    off = run_case(case, seed)
                on = baseline[(case, seed)]
                row = {
                    "rule": rule.name,
                    "case": case.label,
                    "seed": seed,
                    "held_out": seed not in DESIGN_SEEDS,
                    "e3d_with": on["e3d"],
                    "e3d_without": off["e3d"],
                    "active": on.get("digest") != off.get("digest"),
                    "seconds_with": on["seconds"],
                    "seconds_without": off["seconds"],
                    "errors": [x["error"] for x in (on, off) if "error" in x],
                }
                rows.append(row)
                log(
                    f"{rule.name:26s} {case.label:44s} seed {seed:3d}  "
                    f"with {on['e3d']:.4f}  without {off['e3d']:.4f}"
                    f"{'' if row['active'] else '  (same shapes)'}"
                )
    return rows


def _failed(value: float) -> bool:
    return not math.isfinite(value) or value > 1.0


def verdict(rule: Rule, rows: list[dict]) -> dict[str, Any]:
    """The criterion of the module docstring on the held-out rows of one rule."""
    held = [r for r in rows if r["rule"] == rule.name and r["held_out"]]
    if not held:
        return {"rule": rule.name, "keep": None, "reason": "no held-out runs"}
    if not any(r["active"] for r in held):
        return {"rule": rule.name, "keep": False, "reason": "no effect on any held-out solve"}
    prevents = any(_failed(r["e3d_without"]) and not _failed(r["e3d_with"]) for r in held)
    finite = [r for r in held if not _failed(r["e3d_with"]) and not _failed(r["e3d_without"])]
    gains = [r["e3d_without"] - r["e3d_with"] for r in finite]
    mean_with = statistics.fmean(r["e3d_with"] for r in finite) if finite else math.nan
    mean_without = statistics.fmean(r["e3d_without"] for r in finite) if finite else math.nan
    gain = statistics.fmean(gains) if gains else 0.0
    noise = statistics.stdev(gains) / math.sqrt(len(gains)) if len(gains) > 1 else math.inf
    keep = prevents or gain > noise
    reason = (
        "prevents a failure" if prevents else f"mean gain {gain:+.4f} vs standard error {noise:.4f}"
    )
    return {
        "rule": rule.name,
        "keep": keep,
        "held_out_mean_with": mean_with,
        "held_out_mean_without": mean_without,
        "mean_gain": gain,
        "standard_error": noise,
        "reason": reason,
    }


def report_lines(rules: list[Rule], rows: list[dict], verdicts: list[dict]) -> list[str]:
    """The markdown body: the rules, the per-seed table and the verdicts."""
    lines = ["## Rules and neutral settings", ""]
    lines += table(("rule", "where", "switched off"), [(r.name, r.where, r.neutral) for r in rules])
    lines += ["", "## e3D with and without each rule", ""]
    lines += table(
        ("rule", "case", "seed", "with rule", "without", "change without"),
        [
            (
                r["rule"],
                r["case"],
                f"{r['seed']}{'' if r['held_out'] else ' (design)'}",
                f"{r['e3d_with']:.4f}",
                f"{r['e3d_without']:.4f}",
                f"{(r['e3d_without'] / r['e3d_with'] - 1) * 100:+.1f} %"
                if r["e3d_with"] > 0 and math.isfinite(r["e3d_without"])
                else "-",
            )
            for r in rows
        ],
    )
    lines += ["", "## Verdicts (held-out seeds only)", ""]
    lines += table(
        ("rule", "keep", "held-out mean with", "without", "reason"),
        [
            (
                v["rule"],
                {True: "keep", False: "remove", None: "-"}[v["keep"]],
                f"{v.get('held_out_mean_with', math.nan):.4f}",
                f"{v.get('held_out_mean_without', math.nan):.4f}",
                v["reason"],
            )
            for v in verdicts
        ],
    )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rules", nargs="+", choices=[r.name for r in RULES])
    parser.add_argument("--seeds", nargs="+", type=int)
    parser.add_argument("--quick", action="store_true", help="seeds 0 and 301 only")
    parser.add_argument("--output-dir", type=Path, default=RESULTS / "rules")
    args = parser.parse_args(argv)
    rules = [r for r in RULES if args.rules is None or r.name in args.rules]
    seeds = args.seeds or ([0, 301] if args.quick else [*DESIGN_SEEDS, *HELD_OUT_SEEDS])
    meta = provenance(sys.argv if argv is None else ["rule_ablation.py", *argv])
    rows = measure(rules, seeds, lambda line: print(line, flush=True))
    verdicts = [verdict(rule, rows) for rule in rules]
    for v in verdicts:
        print(f"{v['rule']:26s} {v['keep']!s:5s} {v['reason']}")
    args.output_dir.mkdir(parents=True, exist_ok=True)
    write_json(args.output_dir / "rules.json", meta, rows=rows, verdicts=verdicts)
    write_markdown(
        args.output_dir / "rules.md", "Rule ablation", meta, report_lines(rules, rows, verdicts)
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
