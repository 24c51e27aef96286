"""Benchmark of the maximum-depth surface prior (moju_core.priors.max_depth).

Three parts, each writing JSON under benchmarks/results/surface_prior/ (tables in
docs/surface_prior.md):

* ``real``: the four ToTem sequences (pixel tracks through K), e3D with a per-image scale and
  the out-of-plane extent ratio, next to the published MDH and MaxRig depths scored the same
  way, plus an ablation (plain MDH vs edge-length consistency, k, anchors + dense stage).
* ``synthetic``: a perspective sheet bent isometrically into a changing cylinder section,
  seen by a camera that turns only a little, with pixel noise and optional outlier tracks;
  design seeds and held-out seeds reported separately;
* ``timing``: the time of each stage at several sizes.

Usage::

    python benchmarks/surface_prior.py real --data /work/shared/data/totem
    python benchmarks/surface_prior.py real --noise-px 1 --tag _noise1px \
        --variants "plain MDH (k=8, rigidity 0)" "MDH + consistency (k=8)"
    python benchmarks/surface_prior.py synthetic --seeds 0 1 --held-out 2 3 4 --points 1500 \
        --frames 20 --turn 15 --n-anchor 120 [--outliers 0.05 --tag _outliers]
    python benchmarks/surface_prior.py timing --points 5000 20000 --frames 30 --n-anchor 120
    python benchmarks/surface_prior.py timing --points 100000 --frames 5 --n-anchor 120 --tag _100k
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from moju_core.datasets.totem import (
    TOTEM_NAMES,
    load_totem,
    out_of_plane_ratio,
    pixels_to_rays,
    scaled_e3d,
)
from moju_core.priors.max_depth import max_depth_shapes

RESULTS = Path(__file__).resolve().parent / "results" / "surface_prior"
REFERENCE = {  # published scores (data README), per sequence: MDH, MaxRig, best rigid
    "kinectPaper": (0.058, 0.059, 0.115),
    "whiteCartoonTshirt": (0.064, 0.064, 0.366),
    "hulk": (0.075, 0.074, 0.143),
    "cushion": (0.120, 0.113, 0.126),
}


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def bent_sheet(
    n_points: int = 2000,
    n_frames: int = 30,
    *,
    turn_deg: float = 20.0,
    noise_px: float = 0.5,
    focal_px: float = 800.0,
    outlier_fraction: float = 0.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """A 2 x 1.4 sheet bent isometrically along a changing cylinder, seen in perspective.

    Each frame bends the sheet around an axis in its plane (direction changing by up to 40
    degrees) with a bend angle between 40 and 150 degrees over the sheet's width (isometric:
    arc lengths are kept), then places it about 3 units in front of a camera whose viewing
    direction turns by ``turn_deg`` in total over the sequence. Outlier tracks are points whose
    image position jumps by 5-20 px in a third of the frames.

    Returns
    -------
    rays : ndarray of shape (F, P, 2)
        Noisy normalised image coordinates.
    truth : ndarray of shape (F, P, 3)
        True points in each camera frame (sheet units).
    """
    rng = np.random.default_rng(seed)
    uv = rng.uniform([-1.0, -0.7], [1.0, 0.7], size=(n_points, 2))
    phase = rng.uniform(0, 2 * np.pi)
    axis_turn = np.deg2rad(rng.uniform(-40, 40))
    yaw_axis = np.array([0.0, 1.0, 0.0]) + 0.3 * rng.normal(size=3)
    truth = np.empty((n_frames, n_points, 3))
    for f in range(n_frames):
        t = f / max(n_frames - 1, 1)
        bend = np.deg2rad(95 + 55 * np.sin(2 * np.pi * t + phase))
        psi = axis_turn * t
        c, s = np.cos(psi), np.sin(psi)
        a = uv @ np.array([c, s])  # across the bend
        b = uv @ np.array([-s, c])  # along the cylinder axis
        kappa = bend / 2.0
        x = np.sin(kappa * a) / kappa
        z = (1 - np.cos(kappa * a)) / kappa
        local = np.stack([x * c - b * s, x * s + b * c, z], axis=1)
        local -= local.mean(axis=0)
        tilt = _rotation(np.array([1.0, 0.3, 0.0]), np.deg2rad(25))
        turn = _rotation(yaw_axis, np.deg2rad(turn_deg) * (t - 0.5))
        truth[f] = local @ (turn @ tilt).T + np.array([0.0, 0.0, 3.0])
    rays = truth[..., :2] / truth[..., 2:3]
    rays = rays + rng.normal(scale=noise_px / focal_px, size=rays.shape)
    n_out = int(round(outlier_fraction * n_points))
    if n_out:
        who = rng.choice(n_points, n_out, replace=False)
        for p in who:
            frames = rng.choice(n_frames, max(1, n_frames // 3), replace=False)
            jump = rng.uniform(5, 20, size=(frames.size, 1)) / focal_px
            angle = rng.uniform(0, 2 * np.pi, size=(frames.size, 1))
            rays[frames, p] += jump * np.concatenate([np.cos(angle), np.sin(angle)], axis=1)
    return rays, truth


def _score(shapes: np.ndarray, truth: np.ndarray) -> dict:
    return {
        "e3d": round(scaled_e3d(shapes, truth), 4),
        "out_of_plane": round(out_of_plane_ratio(shapes, truth), 3),
    }


def run_real(data: Path, variants: dict[str, dict], noise_px: float = 0.0) -> dict:
    """Score every variant on the four sequences, and the references.

    ``noise_px`` adds Gaussian noise of that standard deviation (pixels, seed 0) to the tracks
    before they go through ``inv(K)``, on top of the tracks' own errors.
    """
    rows: dict = {}
    rng = np.random.default_rng(0)
    for name in TOTEM_NAMES:
        seq = load_totem(data, name)
        if noise_px > 0:
            noisy = seq.pixels + rng.normal(scale=noise_px, size=seq.pixels.shape)
            seq = replace(seq, pixels=noisy, rays=pixels_to_rays(noisy, seq.K))
        rows[name] = {
            "MDH reference": _score(seq.reference_shapes("MDH"), seq.truth),
            "MaxRig reference": _score(seq.reference_shapes("MaxRig"), seq.truth),
        }
        for label, kwargs in variants.items():
            fit = max_depth_shapes(seq.rays, seq.visibility, **kwargs)
            rows[name][label] = {
                **_score(fit.shapes, seq.truth),
                "status": fit.status,
                "seconds": round(fit.seconds["total"], 2),
            }
            print(name, label, rows[name][label], flush=True)
    return rows


def run_synthetic(
    seeds: list[int],
    *,
    n_points: int,
    n_frames: int,
    turn_deg: float,
    outlier_fraction: float,
    kwargs: dict,
) -> list[dict]:
    """Score the prior on bent sheets, one row per seed."""
    rows = []
    for seed in seeds:
        rays, truth = bent_sheet(
            n_points, n_frames, turn_deg=turn_deg, outlier_fraction=outlier_fraction, seed=seed
        )
        fit = max_depth_shapes(rays, None, seed=seed, **kwargs)
        row = {
            "seed": seed,
            **_score(fit.shapes, truth),
            "status": fit.status,
            "seconds": {k: round(v, 2) for k, v in fit.seconds.items()},
            "violation": round(fit.violation, 5),
        }
        print(row, flush=True)
        rows.append(row)
    return rows


REAL_VARIANTS = {
    "plain MDH (k=8, rigidity 0)": {"rigidity": 0.0},
    "MDH + consistency (k=8)": {},
    "MDH + consistency (k=12)": {"k": 12},
    "plain MDH (k=35, as the reference)": {"rigidity": 0.0, "k": 35},
    "MDH + consistency, soft upper bound (outlier price 10)": {"outlier_price": 10.0},
    "40 anchors + interpolation": {"n_anchor": 40, "refine_iter": 0},
    "40 anchors + interpolation + refinement": {"n_anchor": 40, "refine_iter": 60},
}


def _write(name: str, payload: dict) -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    payload = {
        **payload,
        "machine": platform.node(),
        "python": platform.python_version(),
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    (RESULTS / f"{name}.json").write_text(json.dumps(payload, indent=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="part", required=True)
    real = sub.add_parser("real")
    real.add_argument("--data", type=Path, default=Path("/work/shared/data/totem"))
    real.add_argument("--variants", nargs="*", default=list(REAL_VARIANTS))
    real.add_argument("--noise-px", type=float, default=0.0)
    real.add_argument("--tag", default="")
    syn = sub.add_parser("synthetic")
    syn.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    syn.add_argument("--held-out", type=int, nargs="+", default=[2, 3, 4])
    syn.add_argument("--points", type=int, default=2000)
    syn.add_argument("--frames", type=int, default=30)
    syn.add_argument("--turn", type=float, default=15.0)
    syn.add_argument("--outliers", type=float, default=0.0)
    syn.add_argument("--n-anchor", type=int, default=200)
    syn.add_argument("--refine-iter", type=int, default=0)
    syn.add_argument("--tag", default="")
    tim = sub.add_parser("timing")
    tim.add_argument("--points", type=int, nargs="+", default=[5000, 20000])
    tim.add_argument("--frames", type=int, default=30)
    tim.add_argument("--n-anchor", type=int, default=200)
    tim.add_argument("--tag", default="")
    args = parser.parse_args()

    if args.part == "real":
        rows = run_real(args.data, {v: REAL_VARIANTS[v] for v in args.variants}, args.noise_px)
        _write(f"real{args.tag}", {"rows": rows, "published": REFERENCE, "noise_px": args.noise_px})
    elif args.part == "synthetic":
        kwargs = {"n_anchor": args.n_anchor, "refine_iter": args.refine_iter}
        common = dict(
            n_points=args.points,
            n_frames=args.frames,
            turn_deg=args.turn,
            outlier_fraction=args.outliers,
            kwargs=kwargs,
        )
        design = run_synthetic(args.seeds, **common)
        held = run_synthetic(args.held_out, **common)
        summary = {
            part: {
                m: round(float(np.mean([r[m] for r in rows])), 4) for m in ("e3d", "out_of_plane")
            }
            for part, rows in (("design", design), ("held_out", held))
        }
        print(summary)
        _write(
            f"synthetic{args.tag}",
            {
                "settings": {**common, "noise_px": 0.5, "focal_px": 800},
                "design": design,
                "held_out": held,
                "summary": summary,
            },
        )
    else:
        rows = []
        for n in args.points:
            rays, truth = bent_sheet(n, args.frames, turn_deg=15.0, seed=7)
            fit = max_depth_shapes(rays, None, n_anchor=args.n_anchor)
            row = {
                "points": n,
                "frames": args.frames,
                **_score(fit.shapes, truth),
                "n_edges": fit.n_edges,
                "seconds": {k: round(v, 2) for k, v in fit.seconds.items()},
            }
            print(row, flush=True)
            rows.append(row)
        _write(f"timing{args.tag}", {"rows": rows})


if __name__ == "__main__":
    main()
