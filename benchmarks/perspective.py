"""The perspective solve end to end (moju_core.perspective), with its ablation.

For each input, e3D with a per-image scale (``moju_core.datasets.totem.scaled_e3d``) and the
out-of-plane extent ratio of:

* ``orthographic``: ``reconstruct`` without the camera (today's solve of such tracks);
* ``prior alone``: the isometric surface prior's shapes (``perspective.prior_shapes``);
* ``prior + loop``: ``reconstruct(..., intrinsics=K)``, the default perspective solve.

Inputs: the four real ToTem sequences (``--totem DIR``; pixel tracks with their own K) and
perspective bent sheets (``benchmarks/surface_prior.py``'s ``bent_sheet``: 1,500 points,
20 frames, 15 degrees of turn, 0.5 and 1 px of noise at f = 800 px, 2 % outlier tracks;
design seeds and held-out seeds reported apart). Results go to
``benchmarks/results/perspective/``::

    python benchmarks/perspective.py --totem ../shared/data/totem --seeds 0 1 --held-out 2 3
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from moju_core import SolverParams, perspective, reconstruct
from moju_core.cameras.intrinsics import Intrinsics
from moju_core.datasets.totem import TOTEM_NAMES, load_totem, out_of_plane_ratio, scaled_e3d

sys.path.insert(0, str(Path(__file__).parent))
from surface_prior import bent_sheet  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "perspective"
FOCAL = 800.0


def _scores(shapes: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    return {
        "e3d": round(scaled_e3d(shapes, truth), 4),
        "out_of_plane": round(out_of_plane_ratio(shapes, truth), 3),
    }


def compare(W: np.ndarray, visibility: np.ndarray, camera: Intrinsics, truth: np.ndarray):
    """The three solves of one input, W (2F, P) pixels with NaN where hidden."""
    masked = None if visibility.all() else visibility
    rows = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tic = time.perf_counter()
        ortho = reconstruct(W, SolverParams(seed=0), visibility=masked, threads=1)
        rows["orthographic"] = {**_scores(ortho.shapes, truth), "s": time.perf_counter() - tic}
        tic = time.perf_counter()
        prior, _ = perspective.prior_shapes(np.nan_to_num(W), visibility, camera, 0)
        rows["prior alone"] = {**_scores(prior, truth), "s": time.perf_counter() - tic}
        tic = time.perf_counter()
        full = reconstruct(W, SolverParams(seed=0), visibility=masked, intrinsics=camera, threads=1)
        rows["prior + loop"] = {**_scores(full.shapes, truth), "s": time.perf_counter() - tic}
    return rows


def totem_rows(directory: Path) -> dict:
    rows = {}
    for name in TOTEM_NAMES:
        sequence = load_totem(directory, name)
        n_frames, n_points, _ = sequence.pixels.shape
        W = sequence.pixels.transpose(0, 2, 1).reshape(2 * n_frames, n_points)
        rows[name] = compare(W, sequence.visibility, Intrinsics(sequence.K), sequence.truth)
        print(name, rows[name], flush=True)
    return rows


def sheet_rows(seeds: list[int], noise_px: float) -> dict:
    camera = Intrinsics(np.array([[FOCAL, 0.0, 0.0], [0.0, FOCAL, 0.0], [0.0, 0.0, 1.0]]))
    rows = {}
    for seed in seeds:
        rays, truth = bent_sheet(
            1500, 20, turn_deg=15.0, noise_px=noise_px, outlier_fraction=0.02, seed=seed
        )
        n_frames, n_points, _ = rays.shape
        W = (FOCAL * rays).transpose(0, 2, 1).reshape(2 * n_frames, n_points)
        visibility = np.ones((n_frames, n_points), bool)
        rows[f"seed {seed}, {noise_px} px"] = compare(W, visibility, camera, truth)
        print(seed, noise_px, rows[f"seed {seed}, {noise_px} px"], flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--totem", type=Path, default=None)
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1])
    parser.add_argument("--held-out", type=int, nargs="*", default=[2, 3])
    parser.add_argument("--noise", type=float, nargs="*", default=[0.5, 1.0])
    args = parser.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    payload: dict = {}
    if args.totem is not None:
        payload["totem"] = totem_rows(args.totem)
    for label, seeds in (("design", args.seeds), ("held_out", args.held_out)):
        for noise in args.noise:
            payload.setdefault(label, {}).update(sheet_rows(seeds, noise))
    (RESULTS / "perspective.json").write_text(json.dumps(payload, indent=1))


if __name__ == "__main__":
    main()
