"""``moju track`` and ``moju demo --video``, in-process through click's CliRunner.

The videos are small renders of the rolling paper (160 x 120, 12 frames).
"""

from __future__ import annotations

import sys

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

import moju_cli.video_commands as video_commands
from moju_cli.main import cli
from moju_core.footage.render import render_sequence, score_tracks, write_video
from moju_core.footage.video import open_video
from moju_core.neighbour_check import trusted

N_FRAMES = 12


@pytest.fixture(scope="module")
def rendered():
    return render_sequence("paper", width=160, height=120, n_frames=N_FRAMES)


@pytest.fixture(scope="module")
def files(rendered, tmp_path_factory):
    directory = tmp_path_factory.mktemp("video")
    video = write_video(directory / "paper.mp4", rendered.frames)
    mask = directory / "mask.png"
    cv2.imwrite(str(mask), rendered.mask.astype(np.uint8) * 255)
    return {"video": video, "mask": mask}


def _run(*args: str):
    return CliRunner().invoke(cli, [*args], catch_exceptions=False)


def test_track_writes_the_documented_npz(files, rendered, tmp_path):
    output = tmp_path / "tracks.npz"
    outcome = _run("track", str(files["video"]), "-o", str(output), "--mask", str(files["mask"]))
    assert outcome.exit_code == 0, outcome.output
    with np.load(output, allow_pickle=False) as data:
        assert set(data.files) == {"W", "visibility", "colors", "frame_size"}
        W, visibility = data["W"], data["visibility"]
        assert W.shape[0] == 2 * N_FRAMES and visibility.shape == (N_FRAMES, W.shape[1])
        assert data["colors"].shape == (W.shape[1], 3)
        assert list(data["frame_size"]) == [160, 120]
    start = W[:2].T.astype(np.int64)
    assert rendered.mask[start[:, 1], start[:, 0]].all()
    assert score_tracks(rendered, W).median_error < 0.5
    summary = outcome.stdout.splitlines()
    assert summary[0].startswith(f"{W.shape[1]} tracks over {N_FRAMES} frames: ")
    assert f"{visibility.mean():.1%} of the track-frames kept" in summary[0]
    assert " s (" in summary[0] and "ms per frame" in summary[0]
    assert summary[1] == f"tracks: {output}"


def test_track_options_step_start_end(files, tmp_path):
    output = tmp_path / "part.npz"
    outcome = _run(
        "track", str(files["video"]), "-o", str(output), "--mask", str(files["mask"]),
        "--step", "8", "--start", "2", "--end", "7", "--quiet",
    )  # fmt: skip
    assert outcome.exit_code == 0, outcome.output
    with np.load(output) as data:
        assert data["W"].shape[0] == 2 * 5
        assert np.all(data["W"][0] % 8 == 4) and np.all(data["W"][1] % 8 == 4)


def test_track_without_a_mask_warns(files, tmp_path):
    outcome = _run("track", str(files["video"]), "-o", str(tmp_path / "t.npz"), "-q")
    assert outcome.exit_code == 0, outcome.output
    assert "warning: no mask given: tracking the textured region" in outcome.stderr


def test_track_progress_bar_counts_frames(files, tmp_path):
    outcome = _run("track", str(files["video"]), "-o", str(tmp_path / "t.npz"))
    assert f"{N_FRAMES}/{N_FRAMES}" in outcome.stderr


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda path: path.write_text("hello"), "could not be opened as a video"),
        (lambda path: path.write_bytes(b""), "is empty"),
    ],
)
def test_track_refuses_bad_videos_and_writes_nothing(tmp_path, make, message):
    video = tmp_path / "bad.mp4"
    make(video)
    output = tmp_path / "tracks.npz"
    outcome = _run("track", str(video), "-o", str(output))
    assert outcome.exit_code == 1
    assert message in outcome.stderr
    assert not output.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mp4"]


def test_track_refuses_a_mask_of_the_wrong_size(files, tmp_path):
    mask = tmp_path / "mask.png"
    cv2.imwrite(str(mask), np.full((10, 10), 255, dtype=np.uint8))
    outcome = _run("track", str(files["video"]), "-o", str(tmp_path / "t.npz"), "--mask", str(mask))
    assert outcome.exit_code == 1
    assert "10 x 10 pixels, the video's frames are 160 x 120" in outcome.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["-o", "tracks.h5"], "name the file *.npz"),
        (["-o", "missing/tracks.npz"], "does not exist"),
        (["-o", "tracks.npz", "--start", "5", "--end", "5"], "must be after --start"),
        (["-o", "tracks.npz", "--step", "0"], "--step"),
    ],
)
def test_track_usage_errors(files, tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    outcome = _run("track", str(files["video"]), *args)
    assert outcome.exit_code == 2
    assert message in outcome.stderr


def test_demo_video_renders_tracks_and_scores(tmp_path, monkeypatch):
    monkeypatch.setattr(video_commands, "DEMO_VIDEO_SIZE", (160, 120))
    out = tmp_path / "demo"
    outcome = _run("demo", "--video", "--sequence", "paper", "--frames", "10", "--out", str(out))
    assert outcome.exit_code == 0, outcome.output
    assert sorted(p.name for p in out.iterdir()) == ["mask.png", "tracks.npz", "video.mp4"]
    lines = outcome.stdout.splitlines()
    assert lines[0].startswith("paper: rendered 10 frames of 160 x 120")
    errors = [line for line in lines if line.startswith("track error against the ground truth")]
    assert len(errors) == 1
    median = float(errors[0].split("median ")[1].split(" px")[0])
    assert median < 0.5
    assert any(line.startswith("kept: ") for line in lines)
    with np.load(out / "tracks.npz") as data:
        assert data["W"].shape[0] == 20


def test_track_without_opencv_says_how_to_install(files, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "cv2", None)  # import cv2 now raises ImportError
    outcome = _run("track", str(files["video"]), "-o", str(tmp_path / "t.npz"))
    assert outcome.exit_code == 1
    assert "pip install 'moju[video]'" in outcome.stderr


# --- moju reconstruct VIDEO ---------------------------------------------------------------


def _ply_colors(path):
    from plyfile import PlyData

    vertex = PlyData.read(str(path))["vertex"]
    return np.stack([vertex["red"], vertex["green"], vertex["blue"]], axis=1)


def test_reconstruct_video_writes_tracks_shapes_and_coloured_ply(files, rendered, tmp_path):
    output, ply = tmp_path / "result.npz", tmp_path / "ply"
    outcome = _run(
        "reconstruct", str(files["video"]), "--mask", str(files["mask"]), "-o", str(output),
        "--ply-dir", str(ply), "--step", "8", "--max-iter", "3", "--quiet",
    )  # fmt: skip
    assert outcome.exit_code == 0, outcome.output
    tracks_path = tmp_path / "result.tracks.npz"
    with np.load(tracks_path, allow_pickle=False) as data:
        W, visibility, colors = data["W"], data["visibility"], data["colors"]
    n_points = W.shape[1]
    assert W.shape[0] == 2 * N_FRAMES and n_points > 20
    assert np.all(visibility.sum(axis=0) >= 2)  # every written track can be solved
    assert not visibility.all()  # the paper rolls away: some tracks are lost, solved as missing
    start = W[:2].T.astype(np.int64)
    first = next(open_video(files["video"]).frames())  # as decoded: mp4 is lossy
    np.testing.assert_array_equal(colors, first[start[:, 1], start[:, 0]])
    assert rendered.mask[start[:, 1], start[:, 0]].all()
    with np.load(output, allow_pickle=False) as result:
        assert result["shapes"].shape == (N_FRAMES, n_points, 3)
        assert np.isfinite(result["shapes"]).all()
        # the observations used: the tracks' positions less those that leave their
        # neighbours' motion (set aside by the perspective solve)
        np.testing.assert_array_equal(result["visibility"], trusted(W, visibility))
    frames = sorted(ply.iterdir())
    assert len(frames) == N_FRAMES
    np.testing.assert_array_equal(_ply_colors(frames[-1]), colors)
    lines = outcome.stdout.splitlines()
    assert f" tracks over {N_FRAMES} frames: " in lines[0]
    assert any(line.startswith(f"{N_FRAMES} frames x {n_points} points (") for line in lines)
    assert f"tracks: {tracks_path}" in lines and f"result: {output}" in lines


def test_reconstruct_image_folder_with_start_and_end(rendered, tmp_path):
    from moju_core.footage.render import write_image_folder

    folder = tmp_path / "frames"
    write_image_folder(folder, rendered.frames)
    output = tmp_path / "part.h5"
    outcome = _run(
        "reconstruct", str(folder), "-o", str(output), "--step", "8", "--start", "2",
        "--end", "8", "--max-iter", "2", "-q",
    )  # fmt: skip
    assert outcome.exit_code == 0, outcome.output
    assert "warning: no mask given" in outcome.stderr
    with np.load(tmp_path / "part.tracks.npz") as data:
        assert data["W"].shape[0] == 2 * 6
        assert np.all(data["W"][0][np.isfinite(data["W"][0])] % 8 == 4)
    assert output.exists()


def test_reconstruct_refuses_a_bad_video_and_writes_nothing(tmp_path):
    video = tmp_path / "bad.mp4"
    video.write_text("hello")
    outcome = _run("reconstruct", str(video), "-o", str(tmp_path / "r.npz"), "-q")
    assert outcome.exit_code == 1
    assert "could not be opened as a video" in outcome.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mp4"]


def test_reconstruct_refuses_tracking_options_for_a_measurement_file(tmp_path):
    from moju_core.datasets import make_sequence
    from moju_core.io import Measurements, write_measurements

    data = make_sequence("face1", n_points=50)
    write_measurements(tmp_path / "in.npz", Measurements(W=data.W))
    outcome = _run("reconstruct", str(tmp_path / "in.npz"), "-o", str(tmp_path / "r.npz"),
                   "--step", "8")  # fmt: skip
    assert outcome.exit_code == 2
    assert "--step only apply to a video input" in outcome.stderr
    assert not (tmp_path / "r.npz").exists()


def test_reconstruct_video_refuses_known_rotations(files, tmp_path):
    outcome = _run("reconstruct", str(files["video"]), "-o", str(tmp_path / "r.npz"),
                   "--rotations", "known")  # fmt: skip
    assert outcome.exit_code == 2
    assert "a video does not have" in outcome.stderr
    assert list(tmp_path.iterdir()) == []


def test_track_and_reconstruct_share_the_tracking_options() -> None:
    """One declaration: the same names and types; reconstruct's defaults are unset."""
    from moju_cli.solver_commands import reconstruct

    track = video_commands.track
    names = ("mask", "step", "start", "end")

    def options(command):
        return {param.name: param for param in command.params if param.name in names}

    def sentence(text: str) -> str:
        return text.split(" [default")[0].rstrip(".").lower()

    tracked, reconstructed = options(track), options(reconstruct)
    assert set(tracked) == set(reconstructed) == set(names)
    for name in names:
        assert tracked[name].type.to_info_dict() == reconstructed[name].type.to_info_dict(), name
        assert reconstructed[name].default is None, name
        assert reconstructed[name].help.startswith("Video only, as for moju track: "), name
        # The same sentence, before the defaults each command shows its own way.
        said = reconstructed[name].help.removeprefix("Video only, as for moju track: ")
        assert sentence(said) == sentence(tracked[name].help), name
    assert tracked["step"].default == 4 and tracked["start"].default == 0


# --- the camera and the tracker's own output -----------------------------------------------


def test_track_stores_the_camera_it_is_given(files, tmp_path):
    focal = tmp_path / "focal.npz"
    outcome = _run("track", str(files["video"]), "-o", str(focal), "--step", "8",
                   "--focal", "200", "-q")  # fmt: skip
    assert outcome.exit_code == 0, outcome.output
    with np.load(focal) as data:
        np.testing.assert_array_equal(data["K"], [[200, 0, 79.5], [0, 200, 59.5], [0, 0, 1]])
    matrix = tmp_path / "K.txt"
    matrix.write_text("150, 0, 80\n0, 160, 60\n0, 0, 1\n")
    given = tmp_path / "given.npz"
    outcome = _run("track", str(files["video"]), "-o", str(given), "--step", "8",
                   "--intrinsics", str(matrix), "-q")  # fmt: skip
    assert outcome.exit_code == 0, outcome.output
    with np.load(given) as data:
        np.testing.assert_array_equal(data["K"], [[150, 0, 80], [0, 160, 60], [0, 0, 1]])


@pytest.mark.parametrize(
    ("content", "exit_code", "message"),
    [
        ("1 0 0\n0 1 0\n0 0 1\n", 2, "use one of them"),  # with --focal as well
        ("1 0 0\n0 1 0\n", 1, "three lines of three numbers"),
    ],
)
def test_track_refuses_a_bad_camera_before_tracking(files, tmp_path, content, exit_code, message):
    matrix = tmp_path / "K.txt"
    matrix.write_text(content)
    extra = ["--focal", "100"] if exit_code == 2 else []
    output = tmp_path / "tracks.npz"
    outcome = _run("track", str(files["video"]), "-o", str(output), "--intrinsics", str(matrix),
                   *extra)  # fmt: skip
    assert outcome.exit_code == exit_code
    assert message in outcome.stderr
    assert not output.exists()


def _warned_drops(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "seen in fewer than 2 frames" in line]


@pytest.fixture(scope="module")
def face_files(tmp_path_factory):
    """The face (160 x 120, 12 frames), whose tracker output has tracks seen in one frame."""
    rendered = render_sequence("face1", width=160, height=120, n_frames=N_FRAMES)
    directory = tmp_path_factory.mktemp("face")
    video = write_video(directory / "face.mp4", rendered.frames)
    mask = directory / "mask.png"
    cv2.imwrite(str(mask), rendered.mask.astype(np.uint8) * 255)
    return {"video": video, "mask": mask}


def test_reconstruct_takes_the_trackers_own_output_as_the_video(face_files, tmp_path):
    """A tracks file as moju track writes it, tracks seen once included, is solved as the
    video is: the same tracks left out, with the same warning, the same points solved."""
    files = face_files
    tracks = tmp_path / "tracks.npz"
    outcome = _run("track", str(files["video"]), "--mask", str(files["mask"]), "-o",
                   str(tracks), "--step", "6", "-q")  # fmt: skip
    assert outcome.exit_code == 0, outcome.output
    with np.load(tracks) as data:
        seen = data["visibility"].sum(axis=0)
    short = int(np.count_nonzero(seen < 2))
    assert short > 0  # the tracker loses some tracks right after the first frame
    from_file = tmp_path / "from_file.npz"
    outcome = _run("reconstruct", str(tracks), "-o", str(from_file), "--max-iter", "2", "-q")
    assert outcome.exit_code == 0, outcome.output
    warned = _warned_drops(outcome.stderr)
    assert warned == [
        f"warning: {short} of {seen.size} tracks are seen in fewer than 2 frames (a point "
        f"seen once gives no depth) and are left out; {seen.size - short} are kept"
    ]
    # No camera given: the default of the frame size, whose focal length the solve estimates
    # (it says which it used).
    assert "(estimated from the tracks" in outcome.stdout or "(default: 1.2 x" in outcome.stdout
    from_video = tmp_path / "from_video.npz"
    outcome = _run("reconstruct", str(files["video"]), "--mask", str(files["mask"]), "-o",
                   str(from_video), "--step", "6", "--max-iter", "2", "-q")  # fmt: skip
    assert outcome.exit_code == 0, outcome.output
    assert _warned_drops(outcome.stderr) == warned
    from moju_core.io import read_result

    file_result, video_result = read_result(from_file), read_result(from_video)
    assert file_result.shapes.shape == video_result.shapes.shape
    assert file_result.shapes.shape[1] == seen.size - short
    np.testing.assert_array_equal(file_result.visibility, video_result.visibility)
    plan = file_result.diagnostics.plan
    focal = plan.focal_px
    used = {"K": [[focal, 0.0, 79.5], [0.0, focal, 59.5], [0.0, 0.0, 1.0]],
            "origin": plan.focal_origin}  # fmt: skip
    assert plan.focal_origin in ("default", "estimated")
    assert plan.focal_origin == "estimated" or focal == 192.0  # the default: 1.2 x 160 px
    assert file_result.metadata["intrinsics"] == video_result.metadata["intrinsics"] == used
    assert video_result.diagnostics.plan.focal_px == focal


def test_reconstruct_takes_the_camera_options(files, tmp_path):
    tracks = tmp_path / "tracks.npz"
    assert _run("track", str(files["video"]), "-o", str(tracks), "--step", "8",
                "-q").exit_code == 0  # fmt: skip
    output = tmp_path / "r.npz"
    outcome = _run("reconstruct", str(tracks), "-o", str(output), "--focal", "300",
                   "--max-iter", "1", "-q")  # fmt: skip
    assert outcome.exit_code == 0, outcome.output
    assert "camera: focal 300 x 300 px, principal point (79.5, 59.5) (from --focal)" in (
        outcome.stdout
    )
    from moju_core.io import read_result

    recorded = read_result(output).metadata["intrinsics"]
    assert recorded == {"K": [[300.0, 0.0, 79.5], [0.0, 300.0, 59.5], [0.0, 0.0, 1.0]],
                        "origin": "focal"}  # fmt: skip
    outcome = _run("reconstruct", str(files["video"]), "-o", str(tmp_path / "v.npz"),
                   "--focal", "300", "--intrinsics", str(tracks), "-q")  # fmt: skip
    assert outcome.exit_code == 2 and "use one of them" in outcome.stderr
    assert not (tmp_path / "v.npz").exists()


def test_reconstruct_focal_needs_a_frame_size(tmp_path):
    from moju_core.datasets import make_sequence
    from moju_core.io import Measurements, write_measurements

    data = make_sequence("face1", n_points=50)
    write_measurements(tmp_path / "in.npz", Measurements(W=data.W))
    outcome = _run("reconstruct", str(tmp_path / "in.npz"), "-o", str(tmp_path / "r.npz"),
                   "--focal", "500")  # fmt: skip
    assert outcome.exit_code == 2
    assert "in.npz has no frame_size; give the full matrix with --intrinsics" in outcome.stderr
    assert not (tmp_path / "r.npz").exists()
