"""Accuracy and time of ``moju track`` on rendered videos with ground truth.

Every configuration renders a synthetic sequence (``moju_core.footage.render.render_sequence``),
writes it as an mp4, tracks the mp4 with the first frame's true mask and the default step, and
scores the tracks against the ground truth (``moju_core.footage.render.score_tracks``). Time is wall
clock and process CPU time of the tracking alone (decoding included, rendering excluded).

The 320 x 320 videos are also reconstructed. The solvable tracks (``solvable_tracks``) on
the surface are solved with ``moju_core.reconstruct`` (default parameters, the same seed):
once as tracked, once with perfect tracks of the same points (their true 2D paths, with the
tracker's visibility). Both e3D are against the true 3D paths in pixels
(``moju_core.metrics.e3d``, per-frame Procrustes, no scaling); the ratio tracked / perfect is
the cost of tracking errors. A third solve, of the same points' true paths with every entry
observed ("complete"), shows what the lost track-frames cost.

A short 1280 x 720 video (the 320 x 240 render upscaled 4x) gives the tracking time per frame
at that size.

    python benchmarks/tracking.py            # paper, face1, cloth at 320 x 240; paper, face1
                                             # at 320 x 320 (reconstructed); 40 frames each;
                                             # paper at 1280 x 720, 10 frames (time only)
    python benchmarks/tracking.py --quick    # one small video, to prove it runs
    python benchmarks/tracking.py --ratio    # CPU time per frame pair against one DIS flow

Results: ``benchmarks/results/tracking.json`` and ``tracking.md``.

``--ratio`` measures the tracker's speed in units of the flow it is built on: the CPU time of
``track_frames`` per frame pair (forward, backward and keyframe flows and every check
included; decoding excluded: the frames are decoded once, beforehand) over the CPU time of one
OpenCV DIS flow with the medium preset as it is (``cv2.DISOPTICAL_FLOW_PRESET_MEDIUM``) on the
same consecutive frame pairs, measured side by side in one process: DIS, tracker, DIS, three
times; the ratio of each repeat uses the mean of the two DIS timings around it, and the median
of the three ratios is reported, with the tracks' scores against the ground truth (the same in
every repeat). Videos: the paper at 640 x 480 and the face at 320 x 240, 40 frames each
(``--frames``), rendered, written as mp4 and decoded. Results:
``benchmarks/results/tracking/ratio_LABEL.json`` and ``.md`` (``--label``, default
``current``); with ``PYTHONPATH`` at another checkout the same command measures that
checkout's tracker.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from harness import RESULTS, provenance, table, write_json, write_markdown

from moju_core import reconstruct
from moju_core.footage.render import RenderedVideo, render_sequence, score_tracks, write_video
from moju_core.footage.tracking import (
    DEFAULT_STEP,
    Tracks,
    solvable_tracks,
    track_frames,
    track_video,
)
from moju_core.metrics import e3d
from moju_core.params import SolverParams

FULL = [
    ("paper", 320, 240),
    ("face1", 320, 240),
    ("cloth", 320, 240),
    ("paper", 320, 320),
    ("face1", 320, 320),
]
QUICK = [("paper", 160, 120)]
#: Sizes whose tracks are also reconstructed (tracked against perfect tracks).
RECONSTRUCTED = {(320, 320)}
#: Videos of ``--ratio``: (sequence, width, height).
RATIO_VIDEOS = [("paper", 640, 480), ("face1", 320, 240)]
RATIO_REPEATS = 3
#: The large-frame timing: a render upscaled to 1280 x 720 (rendering at that size is slow).
LARGE = ("paper", 320, 240, 1280, 720)
LARGE_FRAMES = 10


def run_one(name: str, width: int, height: int, n_frames: int, directory: Path) -> dict[str, Any]:
    """Render, encode, track and score one video."""
    video = render_sequence(name, width=width, height=height, n_frames=n_frames)
    path = write_video(directory / f"{name}_{width}x{height}.mp4", video.frames)
    wall, cpu = time.perf_counter(), time.process_time()
    tracks = track_video(path, mask=video.mask)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    scores = score_tracks(video, tracks.W)
    row = {
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
    if (width, height) in RECONSTRUCTED:
        row.update(reconstruction_errors(video, tracks))
    return row


def perfect_tracks(video: RenderedVideo, tracks: Tracks) -> tuple[Tracks, Tracks, np.ndarray]:
    """The solvable on-surface ``tracks`` and perfect tracks of the same points.

    Returns the tracks as tracked, the same points' true 2D paths as W (2F, P) pixels with the
    tracker's visibility (NaN where it lost them) and the points' ground-truth index (P,).
    """
    kept = solvable_tracks(tracks)
    n_frames = kept.n_frames
    index = video.lookup(kept.W.reshape(n_frames, 2, -1)[0].T)
    on = index >= 0
    kept = Tracks(
        W=kept.W[:, on], visibility=kept.visibility[:, on], colors=kept.colors[on],
        frame_size=kept.frame_size,
    )  # fmt: skip
    index = index[on]
    true_W = video.paths_2d[:, index].transpose(0, 2, 1).reshape(2 * n_frames, -1).copy()
    true_W[np.repeat(~kept.visibility, 2, axis=0)] = np.nan
    perfect = Tracks(
        W=true_W, visibility=kept.visibility, colors=kept.colors, frame_size=kept.frame_size
    )
    return kept, perfect, index


def reconstruction_errors(video: RenderedVideo, tracks: Tracks) -> dict[str, Any]:
    """e3D of reconstructions from ``tracks`` and from perfect tracks of the same points."""
    kept, perfect, index = perfect_tracks(video, tracks)
    truth = video.paths_3d[:, index] * video.scale  # pixels, the units of W and the shapes
    params = SolverParams()
    out: dict[str, Any] = {"solved_points": int(index.size), "seed": params.seed}
    n_frames = video.n_frames
    complete = Tracks(
        W=video.paths_2d[:, index].transpose(0, 2, 1).reshape(2 * n_frames, -1),
        visibility=np.ones_like(kept.visibility), colors=kept.colors, frame_size=kept.frame_size,
    )  # fmt: skip
    for label, source in (("tracked", kept), ("perfect", perfect), ("complete", complete)):
        start = time.perf_counter()
        result = reconstruct(source.W, params, visibility=source.visibility)
        out[f"e3d_{label}"] = e3d(result.shapes, truth)
        out[f"solve_{label}_s"] = time.perf_counter() - start
    out["e3d_ratio"] = out["e3d_tracked"] / out["e3d_perfect"]
    return out


def time_large(directory: Path) -> dict[str, Any]:
    """Tracking time per frame of a 1280 x 720 video: a small render upscaled (cubic)."""
    name, width, height, big_w, big_h = LARGE
    video = render_sequence(name, width=width, height=height, n_frames=LARGE_FRAMES)
    frames = [cv2.resize(f, (big_w, big_h), interpolation=cv2.INTER_CUBIC) for f in video.frames]
    mask = cv2.resize(video.mask.astype(np.uint8), (big_w, big_h), cv2.INTER_NEAREST) > 0
    path = write_video(directory / f"{name}_{big_w}x{big_h}.mp4", np.stack(frames))
    wall, cpu = time.perf_counter(), time.process_time()
    tracks = track_video(path, mask=mask)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return {
        "sequence": f"{name} {width}x{height} upscaled", "width": big_w, "height": big_h,
        "frames": LARGE_FRAMES, "tracks": tracks.n_points, "wall_s": wall, "cpu_s": cpu,
        "kept_fraction": float(tracks.visibility.mean()),
    }  # fmt: skip


def _decoded(path: Path) -> list[np.ndarray]:
    """The RGB frames of a video file as the tracker reads them."""
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(np.ascontiguousarray(frame[:, :, ::-1]))
    capture.release()
    return frames


def _dis_cpu_per_pair(greys: list[np.ndarray]) -> float:
    """CPU seconds of one DIS flow (medium preset, as it is) per consecutive frame pair."""
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    start = time.process_time()
    for first, second in zip(greys[:-1], greys[1:], strict=True):
        dis.calc(first, second, None)
    return (time.process_time() - start) / (len(greys) - 1)


def ratio_one(name: str, width: int, height: int, n_frames: int, directory: Path) -> dict:
    """Tracker CPU time per frame pair over one DIS-medium flow's, median of the repeats."""
    video = render_sequence(name, width=width, height=height, n_frames=n_frames)
    frames = _decoded(write_video(directory / f"{name}_{width}x{height}.mp4", video.frames))
    greys = [cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY) for frame in frames]
    pairs = len(frames) - 1
    repeats = []
    for _ in range(RATIO_REPEATS):
        before = _dis_cpu_per_pair(greys)
        start = time.process_time()
        tracks = track_frames(frames, mask=video.mask)
        tracker = (time.process_time() - start) / pairs
        after = _dis_cpu_per_pair(greys)
        dis = 0.5 * (before + after)
        repeats.append({"tracker_ms": 1000 * tracker, "dis_ms": 1000 * dis, "ratio": tracker / dis})
    scores = score_tracks(video, tracks.W)
    ratios = [r["ratio"] for r in repeats]
    return {
        "sequence": name, "width": width, "height": height, "frames": len(frames),
        "tracks": tracks.n_points, "repeats": repeats, "ratio": float(np.median(ratios)),
        "median_error_px": scores.median_error, "p90_error_px": scores.p90_error,
        "fraction_kept": scores.fraction_kept,
        "fraction_of_visible_kept": scores.fraction_of_visible_kept,
        "fraction_kept_hidden": scores.fraction_kept_occluded,
    }  # fmt: skip


def ratio_main(n_frames: int, label: str) -> None:
    """``--ratio``: the speed of the tracker in DIS-medium flows per frame pair."""
    meta = provenance()
    meta["opencv"] = cv2.__version__
    meta["opencv_threads"] = cv2.getNumThreads()
    rows = []
    with tempfile.TemporaryDirectory() as directory:
        for name, width, height in RATIO_VIDEOS:
            row = ratio_one(name, width, height, n_frames, Path(directory))
            print(row, flush=True)
            rows.append(row)
    out = RESULTS / "tracking"
    write_json(out / f"ratio_{label}.json", meta, label=label, rows=rows)
    body = table(
        ["video", "tracks", "tracker ms CPU / pair", "DIS medium ms CPU / pair",
         "ratio (median of 3)", "ratios", "median px", "p90 px", "kept", "kept of visible",
         "kept hidden"],
        [
            [
                f"{r['sequence']} {r['width']}x{r['height']}, {r['frames']} frames",
                r["tracks"],
                f"{np.median([x['tracker_ms'] for x in r['repeats']]):.1f}",
                f"{np.median([x['dis_ms'] for x in r['repeats']]):.1f}",
                f"{r['ratio']:.2f}",
                ", ".join(f"{x['ratio']:.2f}" for x in r["repeats"]),
                f"{r['median_error_px']:.4f}",
                f"{r['p90_error_px']:.3f}",
                f"{r['fraction_kept']:.1%}",
                f"{r['fraction_of_visible_kept']:.1%}",
                f"{r['fraction_kept_hidden']:.2%}",
            ]
            for r in rows
        ],
    )  # fmt: skip
    body += [
        "",
        f"Label {label!r}. OpenCV {cv2.__version__} ({cv2.getNumThreads()} threads); CPU time "
        "of the process (all threads). Tracker: track_frames on the decoded mp4 frames with the "
        "true first-frame mask, default step; DIS: cv2.DISOPTICAL_FLOW_PRESET_MEDIUM as it is, "
        "on the same consecutive pairs.",
    ]
    write_markdown(out / f"ratio_{label}.md", f"Tracking speed against DIS ({label})", meta, body)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="one small video")
    parser.add_argument(
        "--ratio", action="store_true", help="tracker CPU time per frame pair / DIS medium's"
    )
    parser.add_argument("--label", default="current", help="name of the --ratio results")
    parser.add_argument("--frames", type=int, default=None, help="frames per video [40; 12]")
    parser.add_argument(
        "--only", default=None, help="comma-separated WIDTHxHEIGHT sizes to run (e.g. 320x320)"
    )
    args = parser.parse_args()
    if args.ratio:
        ratio_main(args.frames or 40, args.label)
        return
    meta = provenance()
    configurations = QUICK if args.quick else FULL
    n_frames = args.frames or (12 if args.quick else 40)
    if args.only:
        sizes = {tuple(int(v) for v in size.split("x")) for size in args.only.split(",")}
        configurations = [c for c in configurations if (c[1], c[2]) in sizes]
    rows = []
    large = None
    with tempfile.TemporaryDirectory() as directory:
        for name, width, height in configurations:
            row = run_one(name, width, height, n_frames, Path(directory))
            print(row, flush=True)
            rows.append(row)
        if not args.quick:
            large = time_large(Path(directory))
            print(large, flush=True)
    suffix = "_quick" if args.quick else ""
    write_json(RESULTS / f"tracking{suffix}.json", meta, rows=rows, large=large)
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
    body += reconstruction_table([r for r in rows if "e3d_ratio" in r])
    if large is not None:
        body += [
            "",
            "## Tracking time at 1280 x 720",
            "",
            f"{large['sequence']} to {large['width']}x{large['height']}, {large['frames']} "
            f"frames, {large['tracks']} tracks: {1000 * large['wall_s'] / large['frames']:.0f} "
            f"ms/frame wall, {1000 * large['cpu_s'] / large['frames']:.0f} ms/frame CPU "
            f"({large['kept_fraction']:.1%} of the track-frames kept).",
        ]
    write_markdown(RESULTS / f"tracking{suffix}.md", "Tracking on rendered videos", meta, body)


def reconstruction_table(rows: list[dict[str, Any]]) -> list[str]:
    """Markdown lines comparing reconstructions from tracks and from perfect tracks."""
    if not rows:
        return []
    return [
        "",
        "## Reconstruction from the tracks against perfect tracks of the same points",
        "",
        "Default solver parameters, the same seed; e3D against the true 3D paths. Perfect: the",
        "true 2D paths with the tracker's visibility; complete: the true 2D paths, all observed.",
        "",
        *table(
            [
                "video",
                "solved tracks",
                "e3D tracked",
                "e3D perfect",
                "tracked / perfect",
                "e3D complete",
                "solve s (tracked, perfect, complete)",
            ],
            [
                [
                    f"{r['sequence']} {r['width']}x{r['height']}, {r['frames']} frames",
                    r["solved_points"],
                    f"{r['e3d_tracked']:.4f}",
                    f"{r['e3d_perfect']:.4f}",
                    f"{r['e3d_ratio']:.3f}",
                    f"{r['e3d_complete']:.4f}",
                    f"{r['solve_tracked_s']:.0f}, {r['solve_perfect_s']:.0f}, "
                    f"{r['solve_complete_s']:.0f}",
                ]
                for r in rows
            ],
        ),  # fmt: skip
    ]


if __name__ == "__main__":
    main()
