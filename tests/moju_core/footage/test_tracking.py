"""Dense tracking (moju_core.footage.tracking) and video reading (moju_core.footage.video).

Accuracy is measured on a small rendered video of the rolling paper (160 x 120, 20 frames)
against its ground truth; occlusion on a synthetic scene where a textured square slides over a
textured background; hostile inputs must raise VideoError with a message saying what is wrong.
"""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest
from numpy.testing import assert_array_equal
from scipy.ndimage import gaussian_filter

from moju_core.errors import Cancelled, VideoError, VideoTooLarge
from moju_core.footage.render import render_sequence, score_tracks, write_image_folder, write_video
from moju_core.footage.tracking import Tracks, track_frames, track_video, write_tracks
from moju_core.footage.video import VideoLimits, open_video

SIZE = (160, 120)
N_FRAMES = 20


@pytest.fixture(scope="module")
def paper():
    return render_sequence("paper", width=SIZE[0], height=SIZE[1], n_frames=N_FRAMES)


@pytest.fixture(scope="module")
def video_files(paper, tmp_path_factory):
    """The paper as an mp4, its decoded frames as a PNG folder, and its mask as a PNG."""
    directory = tmp_path_factory.mktemp("video")
    mp4 = write_video(directory / "paper.mp4", paper.frames)
    capture = cv2.VideoCapture(str(mp4))
    decoded = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        decoded.append(frame[:, :, ::-1])
    capture.release()
    folder = directory / "frames"
    write_image_folder(folder, np.stack(decoded))
    mask = directory / "mask.png"
    cv2.imwrite(str(mask), paper.mask.astype(np.uint8) * 255)
    return {"mp4": mp4, "folder": folder, "mask": mask}


@pytest.fixture(scope="module")
def paper_tracks(paper):
    return track_frames(paper.frames, mask=paper.mask)


def _positions(tracks: Tracks) -> np.ndarray:
    return tracks.W.reshape(tracks.n_frames, 2, -1).transpose(0, 2, 1)


# --- accuracy ------------------------------------------------------------------------------


def test_tracks_follow_the_true_motion(paper, paper_tracks):
    scores = score_tracks(paper, paper_tracks.W)
    assert scores.n_off_surface == 0
    assert scores.median_error < 0.3
    assert scores.p90_error < 1.0
    assert scores.fraction_of_visible_kept > 0.85
    assert scores.fraction_kept_occluded < 0.05
    # A tracker that stays at the first-frame positions is far outside these bounds.
    frozen = np.repeat(paper_tracks.W[:2], paper.n_frames, axis=0)
    assert score_tracks(paper, frozen).median_error > 3.0


def test_tracks_layout(paper, paper_tracks):
    tracks = paper_tracks
    n_points = tracks.n_points
    assert tracks.W.shape == (2 * N_FRAMES, n_points) and tracks.W.dtype == np.float64
    assert tracks.visibility.shape == (N_FRAMES, n_points)
    assert_array_equal(tracks.visibility, np.isfinite(tracks.W[0::2]))
    assert_array_equal(np.isfinite(tracks.W[0::2]), np.isfinite(tracks.W[1::2]))
    # Lost for good: once NaN, NaN in every later frame.
    assert not (~tracks.visibility[:-1] & tracks.visibility[1:]).any()
    assert tracks.frame_size == SIZE
    # Colours are the first frame's pixels under the grid points.
    start = tracks.W[:2].T.astype(np.int64)
    assert_array_equal(tracks.colors, paper.frames[0][start[:, 1], start[:, 0]])
    assert tracks.colors.dtype == np.uint8


# --- occlusion -----------------------------------------------------------------------------


def _occlusion_scene(n_frames: int = 16):
    """A background moving right by 1 px/frame, under a 40 x 40 square moving left by 3."""
    rng = np.random.default_rng(0)

    def texture(height: int, width: int) -> np.ndarray:
        noise = gaussian_filter(rng.standard_normal((height, width, 3)), (1.5, 1.5, 0))
        return np.clip(128 + 50 * noise / noise.std(), 0, 255).astype(np.uint8)

    width, height = SIZE
    background, square = texture(height, width + n_frames), texture(40, 40)
    frames = []
    for t in range(n_frames):
        frame = background[:, n_frames - t : n_frames - t + width].copy()
        left = 110 - 3 * t
        frame[40:80, left : left + 40] = square
        frames.append(frame)
    return frames


def test_occluded_tracks_are_dropped():
    frames = _occlusion_scene()
    tracks = track_frames(frames, mask=np.ones(SIZE[::-1], dtype=bool), step=4)
    start = _positions(tracks)[0]
    on_square = (
        (start[:, 0] >= 110) & (start[:, 0] < 150) & (start[:, 1] >= 40) & (start[:, 1] < 80)
    )
    covered = np.zeros(tracks.visibility.shape, dtype=bool)  # background point 3 px under it
    touched = np.zeros(tracks.n_points, dtype=bool)  # background point ever near the square
    for t in range(len(frames)):
        x, y, left = start[:, 0] + t, start[:, 1], 110 - 3 * t
        covered[t] = ~on_square & (x >= left + 3) & (x < left + 37) & (y >= 43) & (y < 77)
        touched |= ~on_square & (x >= left - 4) & (x < left + 44) & (y >= 36) & (y < 84)
    assert covered.sum() > 300
    # Without the consistency checks every one of these track-frames is kept (measured).
    assert tracks.visibility[covered].mean() < 0.05
    # Background far from the square is kept (except where it leaves the frame on the right).
    stays_inside = start[:, 0] + len(frames) - 1 <= SIZE[0] - 1
    free = ~on_square & ~touched & stays_inside
    assert tracks.visibility[-1, free].mean() > 0.95
    # Of those, the ones kept to the end are where the background is. (The few lost are in
    # the row 6 px below the square: the flow gradient of the boundary check is taken 3 px
    # apart, so it reaches that close to an occluding edge.)
    kept = free & tracks.visibility[-1]
    truth = start[kept] + [len(frames) - 1, 0]
    error = np.linalg.norm(_positions(tracks)[-1, kept] - truth, axis=1)
    # (A few tracks drift by about a pixel over the 15 frames; measured maximum 1.3.)
    assert np.median(error) < 0.1 and error.max() < 2.0
    # The square itself is followed (its inside, away from its edges).
    inner = on_square & (start[:, 0] >= 114) & (start[:, 0] < 146)
    inner &= (start[:, 1] >= 44) & (start[:, 1] < 76)
    assert tracks.visibility[-1, inner].mean() > 0.9


# --- mask and grid -------------------------------------------------------------------------


def test_mask_restricts_the_points(paper):
    mask = np.zeros(SIZE[::-1], dtype=bool)
    mask[30:70, 40:100] = True
    mask &= paper.mask
    tracks = track_frames(paper.frames[:3], mask=mask, step=5)
    start = tracks.W[:2].T.astype(np.int64)
    assert mask[start[:, 1], start[:, 0]].all()
    ys, xs = np.nonzero(mask)
    on_grid = (xs % 5 == 2) & (ys % 5 == 2)
    assert tracks.n_points == on_grid.sum()


def test_without_a_mask_the_textured_region_is_tracked_with_a_warning(paper):
    with pytest.warns(UserWarning, match="no mask given"):
        tracks = track_frames(paper.frames[:3], step=4)
    start = tracks.W[:2].T.astype(np.int64)
    on_surface = paper.mask[start[:, 1], start[:, 0]]
    # The uniform background is not tracked; the surface is (up to its rim).
    assert on_surface.mean() > 0.97
    assert tracks.n_points > 0.9 * paper.mask[2::4, 2::4].sum()


def test_no_point_on_the_mask_is_an_error(paper):
    mask = np.zeros(SIZE[::-1], dtype=bool)
    mask[0, 0] = True
    with pytest.raises(VideoError, match="no grid point"):
        track_frames(paper.frames[:3], mask=mask, step=4)


# --- sources -------------------------------------------------------------------------------


def test_video_file_and_image_folder_give_the_same_tracks(video_files):
    from_video = track_video(video_files["mp4"], mask=video_files["mask"])
    from_folder = track_video(video_files["folder"], mask=video_files["mask"])
    assert from_video.n_frames == N_FRAMES
    assert_array_equal(from_video.W, from_folder.W)
    assert_array_equal(from_video.colors, from_folder.colors)


def test_start_and_end_choose_the_frames(video_files, paper):
    part = track_video(video_files["folder"], mask=paper.mask, start=5, end=12)
    frames = [
        cv2.imread(str(path))[:, :, ::-1] for path in open_video(video_files["folder"]).images
    ]
    direct = track_frames(frames[5:12], mask=paper.mask)
    assert part.n_frames == 7
    assert_array_equal(part.W, direct.W)
    with pytest.raises(VideoError, match="past the last one"):
        track_video(video_files["mp4"], mask=paper.mask, start=N_FRAMES)
    with pytest.raises(ValueError, match="end must be"):
        track_video(video_files["mp4"], mask=paper.mask, start=5, end=5)


def test_progress_and_cancellation(video_files):
    seen = []
    track_video(video_files["mp4"], mask=video_files["mask"], end=6, callback=seen.append)
    assert [progress.frame for progress in seen] == list(range(1, 7))
    assert all(progress.n_frames == 6 for progress in seen)
    with pytest.raises(Cancelled):
        track_video(video_files["mp4"], mask=video_files["mask"], callback=lambda p: p.frame == 3)


def test_write_tracks_round_trip(paper_tracks, tmp_path):
    path = tmp_path / "tracks.npz"
    write_tracks(path, paper_tracks)
    with np.load(path, allow_pickle=False) as data:
        assert set(data.files) == {"W", "visibility", "colors", "frame_size"}
        assert_array_equal(data["W"], paper_tracks.W)  # NaN where lost
        assert np.isnan(data["W"]).any()
        assert data["visibility"].dtype == bool
        assert_array_equal(data["visibility"], paper_tracks.visibility)
        assert data["colors"].dtype == np.uint8
        assert_array_equal(data["frame_size"], SIZE)
    assert [p.name for p in tmp_path.iterdir()] == ["tracks.npz"]  # no temporary left


# --- hostile inputs ------------------------------------------------------------------------


def _png_header(path, width: int, height: int) -> None:
    """A PNG whose header declares ``width`` x ``height`` (the data is garbage)."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    body = struct.pack(">I", 13) + chunk + struct.pack(">I", zlib.crc32(chunk))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + body + b"\x00" * 64)


def test_not_a_video(tmp_path):
    path = tmp_path / "notes.mp4"
    path.write_text("these are not the frames you are looking for\n" * 50)
    with pytest.raises(VideoError, match="could not be opened as a video"):
        track_video(path)
    empty = tmp_path / "empty.mp4"
    empty.write_bytes(b"")
    with pytest.raises(VideoError, match="empty"):
        track_video(empty)
    with pytest.raises(VideoError, match="does not exist"):
        track_video(tmp_path / "missing.mp4")


@pytest.mark.parametrize(("suffix", "message"), [(".mp4", "could not be opened"),
                                                 (".avi", "looks truncated"),
                                                 (".webm", "looks truncated")])  # fmt: skip
def test_truncated_video(paper, tmp_path, suffix, message):
    data = write_video(tmp_path / f"whole{suffix}", paper.frames).read_bytes()
    cut = tmp_path / f"cut{suffix}"
    cut.write_bytes(data[: int(0.6 * len(data))])
    with pytest.raises(VideoError, match=message):
        track_video(cut, mask=paper.mask)


def test_zero_and_one_frame_videos(paper, tmp_path):
    one = write_video(tmp_path / "one.avi", paper.frames[:1])
    with pytest.raises(VideoError, match="one frame"):
        track_video(one, mask=paper.mask)
    zero = write_video(tmp_path / "zero.avi", paper.frames[:0])
    with pytest.raises(VideoError):
        track_video(zero, mask=paper.mask)
    folder = tmp_path / "no_images"
    folder.mkdir()
    (folder / "readme.txt").write_text("no frames here")
    with pytest.raises(VideoError, match="holds no"):
        track_video(folder)


def test_limits_are_checked_before_decoding(video_files, tmp_path):
    with pytest.raises(VideoTooLarge, match="160 x 120 pixels; the limit is 100 x 100"):
        track_video(video_files["mp4"], limits=VideoLimits(max_width=100, max_height=100))
    with pytest.raises(VideoTooLarge, match="20 frames to track, the limit is 10"):
        track_video(video_files["mp4"], limits=VideoLimits(max_frames=10))
    with pytest.raises(VideoTooLarge, match="MiB; the limit"):
        track_video(video_files["mp4"], limits=VideoLimits(max_bytes=1000))
    with pytest.raises(VideoTooLarge, match="s to track at 10 frames/s"):
        track_video(video_files["mp4"], limits=VideoLimits(max_seconds=1.0))
    with pytest.raises(VideoTooLarge, match="tracks at step 1; the limit is 100"):
        track_video(
            video_files["mp4"], mask=video_files["mask"], step=1,
            limits=VideoLimits(max_points=100),
        )  # fmt: skip
    # An image whose header declares a huge frame is refused without decoding it.
    huge = tmp_path / "huge"
    huge.mkdir()
    _png_header(huge / "frame_00000.png", 100_000, 100_000)
    with pytest.raises(VideoTooLarge, match="100000 x 100000 pixels"):
        track_video(huge)


def test_images_of_different_sizes(video_files, tmp_path):
    folder = tmp_path / "mixed"
    folder.mkdir()
    images = sorted(video_files["folder"].iterdir())
    for image in images[:3]:
        (folder / image.name).write_bytes(image.read_bytes())
    cv2.imwrite(str(folder / "frame_00003.png"), np.zeros((50, 60, 3), dtype=np.uint8))
    with pytest.raises(VideoError, match="every frame must have the same size"):
        track_video(folder, mask=video_files["mask"])


def test_bad_masks(video_files, tmp_path):
    wrong_size = tmp_path / "small.png"
    cv2.imwrite(str(wrong_size), np.full((60, 80), 255, dtype=np.uint8))
    with pytest.raises(VideoError, match="80 x 60 pixels, the video's frames are 160 x 120"):
        track_video(video_files["mp4"], mask=wrong_size)
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.zeros((120, 160), dtype=np.uint8))
    with pytest.raises(VideoError, match="marks no pixel"):
        track_video(video_files["mp4"], mask=blank)
    not_png = tmp_path / "mask.png"
    not_png.write_text("not an image")
    with pytest.raises(VideoError, match="not a PNG"):
        track_video(video_files["mp4"], mask=not_png)
    huge = tmp_path / "huge.png"
    _png_header(huge, 100_000, 100_000)
    with pytest.raises(VideoError, match="100000 x 100000 pixels, the video's frames"):
        track_video(video_files["mp4"], mask=huge)


# --- bookkeeping ---------------------------------------------------------------------------


def test_flow_sampling_takes_more_points_than_one_remap_row_holds():
    """OpenCV's remap takes maps of fewer than 32767 rows and columns; 100,000 points (the
    default limit) are sampled as the small batches are."""
    from moju_core.footage.tracking import _Flow

    rng = np.random.default_rng(0)
    field = rng.normal(size=(120, 160, 2)).astype(np.float32)
    points = rng.uniform([0, 0], [159, 119], size=(100_000, 2))
    flow = _Flow("dis")
    sampled = flow.sample(field, points)
    batches = np.concatenate([flow.sample(field, part) for part in np.split(points, 100)])
    assert sampled.shape == (100_000, 2)
    assert_array_equal(sampled, batches)
    # Bilinear: at a pixel centre, the field's value.
    assert_array_equal(flow.sample(field, np.array([[3.0, 5.0]]))[0], field[5, 3])


def test_solvable_tracks_leaves_out_tracks_seen_once_with_a_warning():
    from moju_core.footage.tracking import solvable_tracks

    visibility = np.ones((3, 6), dtype=bool)
    visibility[1:, [0, 4]] = False
    W = np.random.default_rng(0).uniform(0, 50, size=(6, 6))
    W[np.repeat(~visibility, 2, axis=0)] = np.nan
    tracks = Tracks(W=W, visibility=visibility, colors=np.zeros((6, 3), np.uint8),
                    frame_size=(64, 48))  # fmt: skip
    with pytest.warns(UserWarning, match=r"^2 of 6 tracks are seen in fewer than 2 frames"):
        kept = solvable_tracks(tracks)
    assert_array_equal(kept.W, W[:, [1, 2, 3, 5]])
    assert kept.frame_size == (64, 48)


def test_write_tracks_stores_a_given_camera_only(paper_tracks, tmp_path):
    from dataclasses import replace

    from moju_core.cameras.intrinsics import Intrinsics
    from moju_core.io import read_measurements

    write_tracks(tmp_path / "default.npz", paper_tracks)
    focal = replace(paper_tracks, intrinsics=Intrinsics.from_focal(200.0, SIZE))
    write_tracks(tmp_path / "focal.npz", focal)
    with np.load(tmp_path / "default.npz") as plain, np.load(tmp_path / "focal.npz") as given:
        assert "K" not in plain.files
        assert_array_equal(given["K"], focal.intrinsics.K)
    with pytest.warns(UserWarning):  # the paper rolls away: some tracks are seen once
        read = read_measurements(tmp_path / "focal.npz", short_tracks="drop")
    assert_array_equal(read.intrinsics.K, focal.intrinsics.K)
    assert read.frame_size == SIZE


def test_a_decoded_frame_larger_than_the_header_declares_is_refused(monkeypatch, tmp_path):
    """The size limit is checked on the header, and every decoded frame against the header: a
    stream whose first header says 96 x 72 and whose later frames are larger stops there."""
    from moju_core.footage import video as video_module

    sizes = iter([(72, 96), (72, 96), (144, 192)])

    class Capture:
        def __init__(self, *args):
            pass

        def read(self):
            height, width = next(sizes, (0, 0))
            return height > 0, np.zeros((height, width, 3), np.uint8)

        def release(self):
            pass

    monkeypatch.setattr(cv2, "VideoCapture", Capture)
    info = video_module.VideoInfo(
        path=tmp_path / "grows.mp4",
        width=96,
        height=72,
        n_frames=3,
        fps=25.0,
        limits=VideoLimits(),
    )
    with pytest.raises(VideoError, match="frame 2 is 192 x 144, the video declares 96 x 72"):
        list(info.frames())
