"""One solve, two versions of the code, side by side: e3D, chosen weights and the median time
of alternating fresh processes.

    python benchmarks/side_by_side.py --base c4487c1 --sequences bumps-osc face3 --seeds 0 5
    python benchmarks/side_by_side.py --base HEAD~3 --rotations estimated --repeats 3
    python benchmarks/side_by_side.py --base HEAD~1 --noise 0.01 0.03 --points 2000
    python benchmarks/side_by_side.py --base HEAD~1 --noise 0.02 --occlusion combined dropout-0.3
    python benchmarks/side_by_side.py --base HEAD~1 --sequences face4 --points 41 --frames 350

``--base`` is any git revision of this repository; it is checked out into a temporary
worktree, and every solve runs once per repeat in a fresh process of each version, the two
alternating, on one BLAS thread, so that both see the same machine load. The time is the
median over the repeats of ``Result.timings["total"]``; the ratio is this checkout's over the
base's. ``--occlusion`` hides entries (:func:`moju_core.datasets.occlusion_mask`, seeded
like the solve): ``combined`` is the missing-data benchmark's closing configuration. Writes
``side_by_side.json`` and ``side_by_side.md`` into ``--output-dir``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from harness import RESULTS, provenance, table, write_json, write_markdown

ROOT = Path(__file__).resolve().parent.parent
#: Points per sequence: the faces at the size of the face rows, the rest at the hard size.
POINTS = {"face1": 2_000, "face2": 2_000, "face3": 2_000, "face4": 2_000}
DEFAULT_POINTS = 10_000
#: ``--occlusion`` names -> :func:`moju_core.datasets.occlusion_mask` settings (None: complete).
OCCLUSIONS: dict[str, dict[str, float] | None] = {
    "none": None,
    "combined": {"band": 0.2, "lost": 0.1, "dropout": 0.02},
    "dropout-0.1": {"band": 0.0, "lost": 0.0, "dropout": 0.1},
    "dropout-0.3": {"band": 0.0, "lost": 0.0, "dropout": 0.3},
    "band-0.3": {"band": 0.3, "lost": 0.15, "dropout": 0.0},
}

SOLVE = r"""
import json, sys
from threadpoolctl import threadpool_limits
from moju_core import SolverParams, reconstruct
from moju_core.datasets import make_sequence, occlusion_mask
from moju_core.metrics import evaluate
from moju_core.validation import with_missing
name, seed, n_points, source = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
noise, hide, n_frames = float(sys.argv[5]), json.loads(sys.argv[6]), json.loads(sys.argv[7])
data = make_sequence(name, n_points=n_points, n_frames=n_frames, seed=seed, noise=noise)
known = source == "known"
params = SolverParams(seed=seed, **({"rotations": "known"} if known else {}))
W, visibility = data.W, None
if hide is not None:
    visibility = occlusion_mask(data, **hide, seed=seed)
    W = with_missing(data.W, visibility)
with threadpool_limits(limits=1):
    result = reconstruct(W, params, rotations=data.rotations if known else None,
                         visibility=visibility)
score = evaluate(result.shapes, data.shapes, result.rotations, data.rotations)
print(json.dumps({
    "e3d": score["e3d_procrustes"], "rotation_error_deg": score["rotation_error_deg"],
    "smoothness": result.params.smoothness, "unshrunk_values": result.params.unshrunk_values,
    "seconds": result.timings["total"], "n_iter": result.n_iter,
    "rotation_source": result.diagnostics.rotation_source,
}))
"""


def solve_in(
    tree: Path,
    name: str,
    seed: int,
    n_points: int,
    source: str,
    noise: float,
    occlusion: str = "none",
    n_frames: int | None = None,
) -> dict[str, Any]:
    """One solve in a fresh interpreter that imports ``moju_core`` from ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
    hide = json.dumps(OCCLUSIONS[occlusion])
    args = [sys.executable, "-c", SOLVE, name, str(seed), str(n_points), source, str(noise), hide]
    args.append(json.dumps(n_frames))
    done = subprocess.run(args, cwd=tree, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{name} seed {seed} in {tree} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def compare(
    base: Path,
    name: str,
    seed: int,
    source: str,
    repeats: int,
    noise: float = 0.0,
    n_points: int | None = None,
    occlusion: str = "none",
    n_frames: int | None = None,
) -> dict[str, Any]:
    """Alternating solves of the base and of this checkout; the row of one comparison."""
    n_points = n_points or POINTS.get(name, DEFAULT_POINTS)
    runs: dict[str, list[dict[str, Any]]] = {"base": [], "new": []}
    case = (name, seed, n_points, source, noise, occlusion, n_frames)
    for _ in range(repeats):
        runs["base"].append(solve_in(base, *case))
        runs["new"].append(solve_in(ROOT, *case))
    row: dict[str, Any] = {"sequence": name, "seed": seed, "rotations": source, "noise": noise}
    row["occlusion"] = occlusion
    row["n_points"] = n_points
    row["n_frames"] = n_frames
    for label, results in runs.items():
        first = results[0]
        row[label] = {**first, "seconds": statistics.median(r["seconds"] for r in results)}
    row["e3d_ratio"] = row["new"]["e3d"] / row["base"]["e3d"]
    row["time_ratio"] = row["new"]["seconds"] / row["base"]["seconds"]
    print(describe(row), flush=True)
    return row


def describe(row: dict[str, Any]) -> str:
    base, new = row["base"], row["new"]
    return (
        f"{row['sequence']} s{row['seed']} {row['rotations']} noise {row.get('noise', 0.0):g}"
        f" occlusion {row.get('occlusion', 'none')}: "
        f"e3D {base['e3d']:.4f} -> "
        f"{new['e3d']:.4f} (weight {base['smoothness']:g} -> {new['smoothness']:g}), time "
        f"{base['seconds']:.1f} -> {new['seconds']:.1f} s ({row['time_ratio']:.2f}x)"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", required=True, help="git revision to compare against")
    parser.add_argument("--sequences", nargs="+", default=["bumps-osc", "flag-osc", "face3"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--rotations", nargs="+", default=["known"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--noise", nargs="+", type=float, default=[0.0], help="lambda_g levels")
    parser.add_argument("--points", type=int, default=None, help="points (default: per sequence)")
    parser.add_argument("--frames", type=int, default=None, help="frames (default: per sequence)")
    parser.add_argument("--occlusion", nargs="+", choices=sorted(OCCLUSIONS), default=["none"])
    parser.add_argument("--output-dir", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    meta = provenance(sys.argv if argv is None else ["side_by_side.py", *argv])
    with tempfile.TemporaryDirectory() as scratch:
        base = Path(scratch) / "base"
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base), args.base],
            check=True,
            capture_output=True,
        )
        try:
            rows = [
                compare(
                    base,
                    name,
                    seed,
                    source,
                    args.repeats,
                    noise,
                    args.points,
                    occlusion,
                    args.frames,
                )
                for name in args.sequences
                for noise in args.noise
                for occlusion in args.occlusion
                for seed in args.seeds
                for source in args.rotations
            ]
        finally:
            subprocess.run(
                ["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base)],
                check=False,
                capture_output=True,
            )
    meta["base"] = args.base
    write_json(args.output_dir / "side_by_side.json", meta, rows=rows)
    body = [
        [r["sequence"], r["seed"], r["rotations"], f"{r['noise']:g}", r.get("occlusion", "none")]
        + [f"{r['base']['e3d']:.4f}"]
        + [f"{r['new']['e3d']:.4f}", f"{r['base']['smoothness']:g}", f"{r['new']['smoothness']:g}"]
        + [f"{r['base']['seconds']:.2f}", f"{r['new']['seconds']:.2f}", f"{r['time_ratio']:.2f}"]
        for r in rows
    ]
    header = ["sequence", "seed", "rotations", "lambda_g", "occlusion", "e3D base", "e3D now"]
    header += ["weight base"]
    header += ["weight now", "s base", "s now", "time ratio"]
    write_markdown(
        args.output_dir / "side_by_side.md",
        f"This checkout against {args.base}, side by side (median of {args.repeats} runs)",
        meta,
        table(header, body),
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
