"""Hashes of the solver's results on a small benchmark matrix, to check that a restructure
changes nothing.

Faces, sheets, the oscillating sheets, markers; noise-free and noisy; complete and with missing
data; known and estimated cameras; every method. Each case prints the SHA-256 of its shapes,
rotations and labels (first 16 hex digits) and its e3D, so that two runs (before and after a
change) can be compared line by line::

    python benchmarks/result_hashes.py > before.txt
    ... change ...
    python benchmarks/result_hashes.py > after.txt && diff before.txt after.txt

Small sizes (a few hundred points): the whole matrix takes a few minutes on one core.
"""

from __future__ import annotations

import argparse
import hashlib
import warnings

import numpy as np

from moju_core import SolverParams, reconstruct
from moju_core.datasets import make_sequence
from moju_core.datasets.noise import add_noise
from moju_core.datasets.occlusion import occlusion_mask
from moju_core.metrics import e3d

#: (sequence, frames, points, noise, missing, known cameras, method)
CASES: tuple[tuple[str, int, int, float, bool, bool, str], ...] = (
    ("face3", 40, 400, 0.0, False, True, "moju"),
    ("face3", 40, 400, 0.0, False, False, "moju"),
    ("face3", 40, 400, 0.03, False, True, "moju"),
    ("face3", 40, 400, 0.03, False, False, "moju"),
    ("face3", 40, 400, 0.0, True, True, "moju"),
    ("face3", 40, 400, 0.0, True, False, "moju"),
    ("face3", 40, 400, 0.03, True, True, "moju"),
    ("face3", 40, 400, 0.03, True, False, "moju"),
    ("paper", 30, 400, 0.0, False, False, "moju"),
    ("cloth", 30, 400, 0.01, False, True, "moju"),
    ("bumps-osc", 30, 400, 0.0, False, False, "moju"),
    ("flag-osc", 30, 400, 0.03, True, False, "moju"),
    ("body-osc", 40, 41, 0.0, False, False, "moju"),
    ("body-osc", 40, 41, 0.03, True, True, "moju"),
    ("face3", 40, 400, 0.0, False, True, "sdg"),
    ("face3", 40, 400, 0.0, False, False, "bmm"),
    ("face3", 40, 400, 0.0, True, True, "pta"),
)


def _digest(*arrays: np.ndarray) -> str:
    digest = hashlib.sha256()
    for array in arrays:
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()[:16]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-iter", type=int, default=60)
    args = parser.parse_args()
    for name, n_frames, n_points, noise, masked, known, method in CASES:
        sequence = make_sequence(name, n_frames=n_frames, n_points=n_points, seed=3)
        W = sequence.W if noise == 0 else add_noise(sequence.W, noise, seed=3)
        visibility = None
        if masked:
            visibility = occlusion_mask(sequence, seed=3)
            W = np.where(np.repeat(visibility, 2, axis=0), W, np.nan)
        params = SolverParams(seed=0, max_iter=args.max_iter, method=method)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = reconstruct(
                W,
                params,
                rotations=sequence.rotations if known else None,
                visibility=visibility,
                threads=1,
            )
        error = e3d(result.shapes, sequence.shapes)
        print(
            f"{name:10s} F={n_frames:3d} P={n_points:4d} noise={noise:.2f} "
            f"missing={int(masked)} known={int(known)} {method:5s} "
            f"{_digest(result.shapes, result.rotations, result.labels)} "
            f"n_iter={result.n_iter:3d} e3D={error:.6f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
