"""The articulated body (motion-capture-like markers): methods, complete and with missing data.

For every sequence of ``moju_core.datasets.BODY_SEQUENCE_NAMES`` and seed: moju, bmm and pta
with known rotations, moju with its own cameras, each on the complete tracks and under the
missing-data closing occlusion (``occlusion_mask``: a band over 20 % of the width, 10 % of
the tracks lost, 2 % dropout). Prints one line per solve and writes ``body.json`` and
``body.md`` (e3D per-frame Procrustes, and the e3D target of missing data: 1.25 x complete +
0.005).

    python benchmarks/body.py --seeds 0 1 2 3 --output-dir benchmarks/results
    python benchmarks/body.py --seeds 0 1 --noise 0.01 0.03 --output-dir benchmarks/results

With ``--noise``, every level is run too (``lambda_g``, :func:`moju_core.datasets.add_noise`),
into ``body.{json,md}`` with a noise column.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from harness import describe, provenance, solve, table, write_json, write_markdown

from moju_core.datasets import BODY_SEQUENCE_NAMES, make_sequence, occlusion_mask

CLOSING = {"band": 0.2, "lost": 0.1, "dropout": 0.02}
RUNS = (("moju", "known"), ("bmm", "known"), ("pta", "known"), ("moju", "estimated"))
E3D_FACTOR, E3D_SLACK = 1.25, 0.005


def unit(name: str, seed: int, noise: float = 0.0) -> list[dict[str, Any]]:
    """Every run of ``RUNS`` on one sequence and seed, complete and with missing entries."""
    data = make_sequence(name, seed=seed, noise=noise)
    hidden = occlusion_mask(data, **CLOSING, seed=seed)
    rows = []
    for method, source in RUNS:
        for visibility in (None, hidden):
            row = solve(data, method, rotation_source=source, visibility=visibility)
            row.update(seed=seed, missing=0.0 if visibility is None else 1 - hidden.mean())
            print(f"{describe(row)} [seed {seed}, {100 * row['missing']:.1f} % missing]",
                  flush=True)  # fmt: skip
            rows.append(row)
    return rows


def _check(complete: dict[str, Any], missing: dict[str, Any]) -> list[Any]:
    """A table row's measured cells: missing %, e3D complete and missing, target, met?"""
    target = E3D_FACTOR * complete["e3d"] + E3D_SLACK
    return [
        f"{100 * missing['missing']:.1f}", f"{complete['e3d']:.4f}", f"{missing['e3d']:.4f}",
        f"{target:.4f}", "met" if missing["e3d"] <= target else "**missed**",
        f"{complete['rotation_error_deg']:.1f} / {missing['rotation_error_deg']:.1f}",
    ]  # fmt: skip


def report_lines(rows: list[dict[str, Any]]) -> list[str]:
    """One row per sequence, noise, seed and run: e3D complete and missing, the target, met?"""
    lines = []
    for case in dict.fromkeys((r["sequence"], r["noise"], r["seed"]) for r in rows):
        for method, source in RUNS:
            key = (*case, method, source)
            pair = [
                r
                for r in rows
                if (r["sequence"], r["noise"], r["seed"], r["method"], r["rotations"]) == key
            ]
            complete, missing = sorted(pair, key=lambda r: r["missing"])
            lines.append([*key, *_check(complete, missing)])
    header = [
        "sequence", "noise", "seed", "method", "rotations", "missing %", "e3D complete",
        "e3D missing", "target", "e3D", "rotation error (deg)",
    ]  # fmt: skip
    return table(header, lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", nargs="+", default=list(BODY_SEQUENCE_NAMES),
                        choices=BODY_SEQUENCE_NAMES)  # fmt: skip
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--noise", nargs="+", type=float, default=[0.0])
    parser.add_argument("--output-dir", type=Path, default=Path("benchmarks/results"))
    arguments = parser.parse_args(argv)
    meta = provenance(argv)
    rows = [row for name in arguments.sequences for noise in arguments.noise
            for seed in arguments.seeds for row in unit(name, seed, noise)]  # fmt: skip
    arguments.output_dir.mkdir(parents=True, exist_ok=True)
    write_json(arguments.output_dir / "body.json", meta, rows=rows)
    body = [
        "Markers on an articulated body (`moju_core.datasets.body_sequence`, 350 frames x 41 "
        "markers), complete and under the missing-data closing occlusion; known rotations for "
        "moju, bmm and pta, the solver's own cameras for 'estimated'. e3D per-frame "
        "Procrustes; target of missing data 1.25 x complete + 0.005.",
        "",
        *report_lines(rows),
    ]
    write_markdown(arguments.output_dir / "body.md", "Articulated body", meta, body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
