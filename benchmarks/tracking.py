"""Accuracy and time of ``moju track`` on rendered videos with ground truth.

Every configuration renders a synthetic sequence (``moju_core.render.render_sequence``),
writes it as an mp4, tracks the mp4 with the first frame's true mask and the default step, and
scores the tracks against the ground truth (``moju_core.render.score_tracks``). Time is wall
clock and process CPU time of the tracking alone (decoding included, rendering excluded).

    python benchmarks/tracking.py            # paper, face1, cloth at 320 x 240; paper, face1
                                             # at 320 x 320; 40 frames each
    python benchmarks/tracking.py --quick    # one small video, to prove it runs

Results: ``benchmarks/results/tracking.json`` and ``tracking.md``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
from harness import RESULTS, provenance, table, write_json, write_markdown

from moju_core.render import render_sequence, score_tracks, write_video
from moju_core.tracking import DEFAULT_STEP, track_video

FULL = [
    ("paper", 320, 240),
    ("face1", 320, 240),
    ("cloth", 320, 240),
    ("paper", 320, 320),
    ("face1", 320, 320),
]
QUICK = [("paper", 160, 120)]


def run_one(name: str, width: int, height: int, n_frames: int, directory: Path) -> dict[str, Any]:
    """Render, encode, track and score one video."""
    video = render_sequence(name, width=width, height=height, n_frames=n_frames)
    path = write_video(directory / f"{name}_{width}x{height}.mp4", video.frames)
    wall, cpu = time.perf_counter(), time.process_time()
    tracks = track_video(path, mask=video.mask)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    scores = score_tracks(video, tracks.W)
    return {
        "sequence": name,
        "width": width,
        "height": height,
        "frames": n_frames,
        "tracks": tracks.n_points,
        "median_error_px": scores.median_error,
        "p90_error_px": scores.p90_error,
        "fraction_kept": scores.fraction_kept,
        "fraction_of_visible_kept": scores.fraction_of_visible_kept,
        "fraction_kept_hidden": scores.fraction_kept_occluded,
        "tracked_to_last_frame": float(tracks.visibility[-1].mean()),
        "wall_s": wall,
        "cpu_s": cpu,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="one small video")
    parser.add_argument("--frames", type=int, default=None, help="frames per video [40; 12]")
    args = parser.parse_args()
    meta = provenance()
    configurations = QUICK if args.quick else FULL
    n_frames = args.frames or (12 if args.quick else 40)
    rows = []
    with tempfile.TemporaryDirectory() as directory:
        for name, width, height in configurations:
            row = run_one(name, width, height, n_frames, Path(directory))
            print(row, flush=True)
            rows.append(row)
    suffix = "_quick" if args.quick else ""
    write_json(RESULTS / f"tracking{suffix}.json", meta, rows=rows)
    body = table(
        ["video", "tracks", "median px", "p90 px", "kept", "kept of visible", "kept hidden",
         "to last frame", "ms/frame wall", "ms/frame CPU"],
        [
            [
                f"{r['sequence']} {r['width']}x{r['height']}, {r['frames']} frames",
                r["tracks"],
                f"{r['median_error_px']:.2f}",
                f"{r['p90_error_px']:.2f}",
                f"{r['fraction_kept']:.1%}",
                f"{r['fraction_of_visible_kept']:.1%}",
                f"{r['fraction_kept_hidden']:.2%}",
                f"{r['tracked_to_last_frame']:.1%}",
                f"{1000 * r['wall_s'] / r['frames']:.0f}",
                f"{1000 * r['cpu_s'] / r['frames']:.0f}",
            ]
            for r in rows
        ],
    )  # fmt: skip
    body += [
        "",
        f"OpenCV {cv2.__version__}; DIS flow, step {DEFAULT_STEP} px, true first-frame mask.",
    ]
    write_markdown(RESULTS / f"tracking{suffix}.md", "Tracking on rendered videos", meta, body)


if __name__ == "__main__":
    main()
