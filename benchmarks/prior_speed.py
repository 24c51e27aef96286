"""Time of the perspective surface prior: Clarabel's default settings against the library's.

:data:`moju_core.priors.cone_program.CLARABEL_SETTINGS` changes some of Clarabel's settings
for every cone program of the prior. This script runs
:func:`moju_core.perspective.prior_shapes` on the same inputs with Clarabel's defaults
(``old``) and with the library's settings (``new``), alternating in one process, and reports
the wall-time ratio (new / old, median over ``--repeats`` runs) and the e3D
(``scaled_e3d``, every entry) of each. Inputs: footage scenes rendered and tracked here
(``benchmarks/footage.py``'s scenes at 30 frames, 640 x 480, the tracks as tracked), and the
four ToTem sequences with ``--totem DIR``. Results:
``benchmarks/results/surface_prior/prior_speed[TAG].json`` and ``.md``::

    PYTHONPATH=.:benchmarks nice python benchmarks/prior_speed.py  # crease 1, cloth 2
    PYTHONPATH=.:benchmarks nice python benchmarks/prior_speed.py --scenes curl:0 --tag _curl
    PYTHONPATH=.:benchmarks nice python benchmarks/prior_speed.py --scenes --totem /path/to/totem
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from footage import scene_video
from harness import RESULTS, provenance, table, write_json, write_markdown
from tracking import perfect_tracks

from moju_core.cameras.intrinsics import Intrinsics
from moju_core.datasets.totem import TOTEM_NAMES, load_totem, scaled_e3d
from moju_core.footage.tracking import track_frames
from moju_core.perspective import prior_shapes
from moju_core.priors import cone_program

OUT = RESULTS / "surface_prior"


def scene_inputs(spec: str) -> tuple[np.ndarray, np.ndarray, Intrinsics, np.ndarray]:
    """``W``, visibility, camera and true 3D points of a rendered scene ``kind:seed``."""
    kind, seed = spec.split(":")
    args = argparse.Namespace(frames=30, width=640, height=480, mesh=6000)
    _, video = scene_video(kind, int(seed), args)
    tracks = replace(track_frames(list(video.frames), mask=video.mask), intrinsics=video.intrinsics)
    kept, _, index = perfect_tracks(video, tracks)
    return kept.W, kept.visibility, video.intrinsics, video.paths_3d[:, index]


def totem_inputs(directory: Path, name: str) -> tuple[np.ndarray, ...]:
    """``W``, visibility, camera and true 3D points of a ToTem sequence."""
    sequence = load_totem(directory, name)
    n_frames, n_points, _ = sequence.pixels.shape
    W = sequence.pixels.transpose(0, 2, 1).reshape(2 * n_frames, n_points)
    return W, sequence.visibility, Intrinsics(sequence.K), sequence.truth


def timed_prior(inputs: tuple, settings: dict[str, Any]) -> tuple[float, float, int]:
    """Wall time, e3D and cone programs solved of the prior under Clarabel ``settings``."""
    W, visibility, camera, truth = inputs
    saved = cone_program.CLARABEL_SETTINGS
    cone_program.CLARABEL_SETTINGS = settings
    try:
        start = time.perf_counter()
        shapes, fit = prior_shapes(W, visibility, camera, 0)
        seconds = time.perf_counter() - start
    finally:
        cone_program.CLARABEL_SETTINGS = saved
    return seconds, float(scaled_e3d(shapes, truth)), fit.n_solves


def compare(inputs: tuple, repeats: int) -> dict[str, Any]:
    """Old and new settings alternating ``repeats`` times on one input."""
    runs: dict[str, list] = {"old": [], "new": []}
    for _ in range(repeats):
        for label, settings in (("old", {}), ("new", dict(cone_program.CLARABEL_SETTINGS))):
            runs[label].append(timed_prior(inputs, settings))
    row: dict[str, Any] = {"frames": int(inputs[1].shape[0]), "points": int(inputs[1].shape[1])}
    for label, results in runs.items():
        row[f"{label}_s"] = [r[0] for r in results]
        row[f"{label}_e3d"] = results[0][1]  # deterministic: the same every run
        row[f"{label}_solves"] = results[0][2]
    row["ratio"] = float(np.median(row["new_s"]) / np.median(row["old_s"]))
    row["e3d_change"] = row["new_e3d"] - row["old_e3d"]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="*", default=["crease:1", "cloth:2"])
    parser.add_argument("--totem", type=Path, default=None)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--tag", default="")
    args = parser.parse_args()
    meta = provenance()
    meta["settings"] = {"old": "Clarabel defaults", "new": dict(cone_program.CLARABEL_SETTINGS)}
    rows: dict[str, dict[str, Any]] = {}
    sources = [(spec, lambda spec=spec: scene_inputs(spec)) for spec in args.scenes]
    if args.totem is not None:
        sources += [
            (name, lambda name=name: totem_inputs(args.totem, name)) for name in TOTEM_NAMES
        ]
    for label, load in sources:
        rows[label] = compare(load(), args.repeats)
        row = rows[label]
        print(
            f"{label}: {row['frames']} x {row['points']}, old {np.median(row['old_s']):.1f} s "
            f"e3D {row['old_e3d']:.4f}, new {np.median(row['new_s']):.1f} s e3D "
            f"{row['new_e3d']:.4f}, ratio {row['ratio']:.3f}",
            flush=True,
        )
    write_json(OUT / f"prior_speed{args.tag}.json", meta, rows=rows)
    body = table(
        ["input", "frames x points", "old s", "new s", "ratio new/old", "old e3D", "new e3D"],
        [
            [
                label,
                f"{r['frames']} x {r['points']}",
                f"{np.median(r['old_s']):.1f}",
                f"{np.median(r['new_s']):.1f}",
                f"{r['ratio']:.3f}",
                f"{r['old_e3d']:.4f}",
                f"{r['new_e3d']:.4f}",
            ]
            for label, r in rows.items()
        ],
    )
    title = "Surface prior: Clarabel settings"
    write_markdown(OUT / f"prior_speed{args.tag}.md", title, meta, body)


if __name__ == "__main__":
    main()
