"""The rendered-video test bed: rasteriser, ground truth, video writing and track scoring.

The ground truth is checked against the pixels themselves: the colour of a frame at a point's
true position must match the point's colour in the first frame, much better than at a wrong
position.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from moju_core.footage.render import (
    rasterize,
    render_sequence,
    score_tracks,
    write_image_folder,
    write_video,
)

SIZE = (160, 120)
N_FRAMES = 20


@pytest.fixture(scope="module")
def paper():
    return render_sequence("paper", width=SIZE[0], height=SIZE[1], n_frames=N_FRAMES)


def _sample(frame: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear grey values of an RGB frame at positions (n, 2)."""
    grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY).astype(np.float32)
    xy = xy.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(grey, xy[..., 0], xy[..., 1], cv2.INTER_LINEAR).ravel()


# --- rasterize -----------------------------------------------------------------------------


def test_rasterize_covers_a_perturbed_grid_without_holes():
    rng = np.random.default_rng(0)
    n = 12
    ys, xs = np.meshgrid(np.linspace(2, 37, n), np.linspace(3, 48, n), indexing="ij")
    inner = (slice(1, -1), slice(1, -1))
    xs[inner] += rng.uniform(-1, 1, (n - 2, n - 2))
    ys[inner] += rng.uniform(-1, 1, (n - 2, n - 2))
    vertices = np.stack([xs.ravel(), ys.ravel()], axis=1)
    corner = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    faces = np.concatenate(
        [
            np.stack([corner, corner + 1, corner + n], axis=1),
            np.stack([corner + 1, corner + n + 1, corner + n], axis=1),
        ]
    )
    triangle, weights, zbuffer = rasterize(vertices, np.zeros(n * n), faces, 42, 52)
    # Every pixel centre inside the outer rectangle [3, 48] x [2, 37] is covered.
    assert (triangle[2:38, 3:49] >= 0).all()
    assert (triangle[:2] == -1).all() and (triangle[:, :3] == -1).all()
    assert (triangle[38:] == -1).all() and (triangle[:, 49:] == -1).all()
    covered = triangle >= 0
    assert np.allclose(weights[covered].sum(axis=1), 1.0)
    # The weights reproduce the pixel centre from the triangle's corners.
    rows, cols = np.nonzero(covered)
    position = np.einsum("nk,nkd->nd", weights[covered], vertices[faces[triangle[covered]]])
    assert np.allclose(position, np.stack([cols, rows], axis=1), atol=1e-9)
    assert np.isneginf(zbuffer[~covered]).all()


def test_rasterize_keeps_the_nearest_triangle():
    vertices = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 20.0]] * 2)
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    depth = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])  # the second is nearer
    triangle, _, zbuffer = rasterize(vertices, depth, faces, 21, 21)
    assert set(np.unique(triangle[triangle >= 0])) == {1}
    assert np.allclose(zbuffer[triangle >= 0], 2.0)


# --- render_sequence -----------------------------------------------------------------------


def test_frames_and_ground_truth_layout(paper):
    width, height = SIZE
    assert paper.frames.shape == (N_FRAMES, height, width, 3)
    assert paper.frames.dtype == np.uint8
    assert paper.frame_size == SIZE
    n = paper.points_xy.shape[0]
    assert n == int(paper.mask.sum()) > 0.2 * width * height
    assert paper.paths_2d.shape == (N_FRAMES, n, 2)
    assert paper.paths_3d.shape == (N_FRAMES, n, 3)
    # The first frame's paths start on their own pixel centres, all visible.
    assert np.allclose(paper.paths_2d[0], paper.points_xy, atol=1e-9)
    assert paper.visible[0].all()
    assert np.array_equal(paper.lookup(paper.points_xy), np.arange(n))
    assert (paper.lookup(np.array([[-5.0, 3.0], [0.0, 0.0]])) == -1).all()


def test_ground_truth_paths_follow_the_texture(paper):
    """Frame f at the true positions looks like frame 0 at the start positions."""
    reference = _sample(paper.frames[0], paper.points_xy)
    motion = np.linalg.norm(paper.paths_2d[-1] - paper.paths_2d[0], axis=1)
    assert np.median(motion) > 5.0  # the surface really moves
    for f in (5, N_FRAMES - 1):
        visible = paper.visible[f]
        on_path = np.abs(_sample(paper.frames[f], paper.paths_2d[f, visible]) - reference[visible])
        at_start = np.abs(_sample(paper.frames[f], paper.points_xy[visible]) - reference[visible])
        assert np.median(on_path) < 3.0
        assert np.median(on_path) < 0.3 * np.median(at_start)


def test_rolling_paper_hides_part_of_itself(paper):
    assert paper.visible[-1].mean() < 0.8
    # Hidden points are those of the rolled end: the paths keep moving for them too.
    assert np.isfinite(paper.paths_2d).all() and np.isfinite(paper.paths_3d).all()


def test_render_is_reproducible_and_seeded():
    small = {"width": 48, "height": 32, "n_frames": 3}
    first = render_sequence("cloth", seed=1, **small)
    again = render_sequence("cloth", seed=1, **small)
    other = render_sequence("cloth", seed=2, **small)
    assert np.array_equal(first.frames, again.frames)
    assert not np.array_equal(first.frames, other.frames)


@pytest.mark.parametrize(
    "kwargs", [{"width": 8}, {"height": 10.5}, {"supersample": 0}, {"n_frames": 1}]
)
def test_render_refuses_bad_sizes(kwargs):
    with pytest.raises(ValueError):
        render_sequence("paper", **kwargs)


# --- output --------------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".mp4", ".avi", ".webm"])
def test_write_video_decodes_back(paper, tmp_path, suffix):
    path = write_video(tmp_path / f"paper{suffix}", paper.frames[:6])
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    decoded = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        decoded.append(frame[:, :, ::-1])
    capture.release()
    assert len(decoded) == 6
    difference = np.abs(np.stack(decoded).astype(float) - paper.frames[:6])
    assert difference.mean() < 8.0  # lossy, but the same pictures


def test_write_video_refuses_unknown_extension(paper, tmp_path):
    with pytest.raises(ValueError, match="unknown video extension"):
        write_video(tmp_path / "paper.gif", paper.frames)


def test_write_image_folder_is_lossless(paper, tmp_path):
    paths = write_image_folder(tmp_path / "frames", paper.frames[:3])
    assert [path.name for path in paths] == [f"frame_{f:05d}.png" for f in range(3)]
    assert np.array_equal(cv2.imread(str(paths[2]))[:, :, ::-1], paper.frames[2])


# --- score_tracks --------------------------------------------------------------------------


def _tracks(positions: np.ndarray) -> np.ndarray:
    """(F, P, 2) positions to W (2F, P)."""
    return positions.transpose(0, 2, 1).reshape(2 * positions.shape[0], -1)


def test_score_of_perfect_and_frozen_tracks(paper):
    chosen = np.arange(0, paper.points_xy.shape[0], 5)
    perfect = score_tracks(paper, _tracks(paper.paths_2d[:, chosen]))
    assert perfect.median_error < 1e-9 and perfect.p90_error < 1e-9
    assert perfect.fraction_kept == 1.0 and perfect.n_tracks == chosen.size
    frozen = np.broadcast_to(paper.paths_2d[:1, chosen], paper.paths_2d[:, chosen].shape)
    assert score_tracks(paper, _tracks(frozen)).median_error > 3.0


def test_score_counts_lost_and_occluded_track_frames(paper):
    positions = paper.paths_2d.copy()
    positions[N_FRAMES // 2 :, ::2] = np.nan  # half the tracks lost half-way
    scores = score_tracks(paper, _tracks(positions))
    assert scores.fraction_kept == pytest.approx(
        1.0 - (N_FRAMES - N_FRAMES // 2) * positions[0, ::2].shape[0] / positions[..., 0].size
    )
    hidden = ~paper.visible
    kept = np.isfinite(positions[..., 0])
    assert scores.fraction_kept_occluded == pytest.approx((kept & hidden).sum() / kept.sum())
    with pytest.raises(ValueError, match="F = "):
        score_tracks(paper, _tracks(positions[:-1]))
