"""Video uploads: checked at submission, tracked then solved by the worker, tracks served.

The video is a tiny render of the rolling paper (96 x 72 pixels, 8 frames); the worker runs
in-process (``worker.jobs.execute``) with the real tracker and solver (max_iter 3).
"""

from __future__ import annotations

import io
import json
import tempfile
import zipfile
from pathlib import Path
from uuid import UUID

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from plyfile import PlyData
from redis import Redis

from moju_core.footage.render import render_sequence, write_video
from moju_core.footage.tracking import count_grid_points
from moju_core.footage.video import open_video
from moju_core.neighbour_check import trusted
from service.app import create_app
from service.job_store import JobStore
from service.settings import Settings
from service.storage import LocalStorage
from worker.jobs import execute

N_FRAMES, SIZE = 8, (96, 72)


@pytest.fixture(scope="module")
def rendered():
    return render_sequence("paper", width=SIZE[0], height=SIZE[1], n_frames=N_FRAMES)


@pytest.fixture(scope="module")
def video_files(rendered, tmp_path_factory):
    directory = tmp_path_factory.mktemp("video")
    video = write_video(directory / "paper.mp4", rendered.frames)
    mask = directory / "mask.png"
    cv2.imwrite(str(mask), rendered.mask.astype(np.uint8) * 255)
    return {"video": video, "mask": mask}


@pytest.fixture
def staging(tmp_path, monkeypatch) -> Path:
    """The temporary directory uploads are staged in, to check that nothing is left."""
    directory = tmp_path / "staging"
    directory.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(directory))
    return directory


def post(client: TestClient, video: bytes, mask: bytes | None = None, params=None):
    files = {"file": ("clip.mp4", video, "application/octet-stream")}
    if mask is not None:
        files["mask"] = ("mask.png", mask, "image/png")
    return client.post("/v1/jobs", files=files, data={"params": json.dumps(params or {})})


def stored_jobs(settings: Settings) -> list[Path]:
    return list((settings.data_dir / "jobs").iterdir())


def test_video_job_tracks_then_solves_and_serves_the_tracks(
    client: TestClient, video_files, rendered, settings: Settings, redis_client: Redis,
    staging: Path,
) -> None:  # fmt: skip
    response = post(
        client, video_files["video"].read_bytes(), video_files["mask"].read_bytes(),
        {"max_iter": 3, "seed": 1},
    )  # fmt: skip
    assert response.status_code == 202, response.text
    job = response.json()
    job_id = job["id"]
    assert job["input"]["format"] == "video" and job["input"]["frames"] == N_FRAMES
    assert job["input"]["points"] == count_grid_points(rendered.mask)
    assert job["input"]["video"] == {
        "width": SIZE[0], "height": SIZE[1], "fps": 10.0, "has_mask": True, "step": 4,
    }  # fmt: skip
    assert job["links"]["tracks"] == f"/v1/jobs/{job_id}/tracks.npz"
    assert list(staging.iterdir()) == []  # the staged upload was moved into the job
    first = client.get(f"/v1/jobs/{job_id}/first-frame.png")
    assert first.status_code == 200 and first.headers["content-type"] == "image/png"
    image = cv2.imdecode(np.frombuffer(first.content, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (SIZE[1], SIZE[0], 3)
    for path in ("tracks.npz", "first-frame.png?overlay=tracks"):
        early = client.get(f"/v1/jobs/{job_id}/{path}")
        assert early.status_code == 409, path
        assert "tracking stage has not ended" in early.json()["detail"]

    store = JobStore(redis_client, retention_seconds=settings.result_ttl)
    stages = []
    report = store.report_progress

    def spy(job, progress, attempt=None):
        stages.append((progress["stage"], progress["iteration"], progress["max_iter"]))
        return report(job, progress, attempt)

    store.report_progress = spy  # type: ignore[method-assign]
    outcome = execute(UUID(job_id), store, LocalStorage(settings.data_dir), settings)
    assert outcome["status"] == "finished", outcome
    assert stages[0] == ("tracking", 1, N_FRAMES)
    assert ("tracking", N_FRAMES, N_FRAMES) in stages or stages[1][0] != "tracking"
    solving = [stage for stage, _, _ in stages if stage != "tracking"]
    assert solving and "iterating" in solving
    first_solve = next(i for i, entry in enumerate(stages) if entry[0] != "tracking")
    assert all(entry[0] == "tracking" for entry in stages[:first_solve])
    assert all(entry[0] != "tracking" for entry in stages[first_solve:])

    finished = client.get(f"/v1/jobs/{job_id}").json()
    assert finished["status"] == "finished"
    tracking = finished["result"]["tracking"]
    tracks = client.get(f"/v1/jobs/{job_id}/tracks.npz")
    assert tracks.status_code == 200
    with np.load(io.BytesIO(tracks.content), allow_pickle=False) as data:
        W, visibility, colors = data["W"], data["visibility"], data["colors"]
        assert list(data["frame_size"]) == list(SIZE)
        assert "K" not in data  # no camera given: the default of the frame size, not stored
    assert finished["input"]["camera"]["source"] == "default"
    assert W.shape == (2 * N_FRAMES, tracking["reconstructed"])
    assert tracking["tracks"] == job["input"]["points"] >= tracking["reconstructed"]
    assert tracking["fraction_kept"] == pytest.approx(visibility.mean(), abs=0.1)
    # The finished job's input says what was solved, not the upload's estimate.
    assert finished["input"]["points"] == tracking["reconstructed"]
    used = trusted(W, visibility)  # less the positions the perspective solve set aside
    assert finished["input"]["observed_fraction"] == pytest.approx(used.mean())
    decoded = next(open_video(video_files["video"]).frames())
    start = W[:2].T.astype(np.int64)
    np.testing.assert_array_equal(colors, decoded[start[:, 1], start[:, 0]])

    result = client.get(f"/v1/jobs/{job_id}/result", params={"format": "npz"})
    with np.load(io.BytesIO(result.content), allow_pickle=False) as data:
        assert data["shapes"].shape == (N_FRAMES, W.shape[1], 3)
        np.testing.assert_array_equal(data["visibility"], used)
    drawn = client.get(f"/v1/jobs/{job_id}/first-frame.png", params={"overlay": "tracks"})
    assert drawn.status_code == 200 and drawn.headers["content-type"] == "image/png"
    overlay = cv2.imdecode(np.frombuffer(drawn.content, np.uint8), cv2.IMREAD_COLOR)
    assert overlay.shape == image.shape
    # Red dots where the tracks were last seen; the rest of the frame around the object kept.
    paths = W.reshape(N_FRAMES, 2, -1).transpose(2, 0, 1)  # (P, F, 2)
    ends = [path[np.isfinite(path[:, 0])][-1] for path in paths]
    x, y = np.round(np.array(ends)).astype(int).T
    assert np.all(overlay[y, x] == [40, 40, 240])  # BGR
    np.testing.assert_array_equal(overlay[0, 0], image[0, 0])
    ply = PlyData.read(io.BytesIO(client.get(f"/v1/jobs/{job_id}/frames/0.ply").content))
    vertex = ply["vertex"]
    np.testing.assert_array_equal(
        np.stack([vertex["red"], vertex["green"], vertex["blue"]], axis=1), colors
    )


def test_a_measurement_job_has_no_tracks(client: TestClient, input_file: Path) -> None:
    files = {"file": (input_file.name, input_file.read_bytes(), "application/octet-stream")}
    job = client.post("/v1/jobs", files=files).json()
    assert job["links"]["tracks"] is None
    for path in ("tracks.npz", "first-frame.png"):
        response = client.get(f"/v1/jobs/{job['id']}/{path}")
        assert response.status_code == 404
        assert "not a video" in response.json()["detail"]


def _one_frame(rendered, directory: Path) -> bytes:
    return write_video(directory / "one.mp4", rendered.frames[:1]).read_bytes()


def _header_only(rendered, directory: Path) -> bytes:
    return b"\x00\x00\x00\x18ftypmp42" + b"\x00" * 2000


def _truncated(rendered, directory: Path) -> bytes:
    data = write_video(directory / "cut.mp4", rendered.frames).read_bytes()
    return data[: len(data) // 2]


@pytest.mark.parametrize(
    ("make", "status", "message"),
    [
        (_header_only, 422, "could not be opened as a video"),
        (_truncated, 422, "could not be opened as a video"),
        (_one_frame, 422, "the video holds one frame"),
    ],
)
def test_unusable_videos_are_refused_and_nothing_is_kept(
    client: TestClient, rendered, settings: Settings, staging: Path, tmp_path: Path,
    make, status, message,
) -> None:  # fmt: skip
    response = post(client, make(rendered, tmp_path))
    assert response.status_code == status, response.text
    assert message in response.json()["detail"]
    assert stored_jobs(settings) == [] and list(staging.iterdir()) == []


@pytest.mark.parametrize(
    ("limit", "status", "message"),
    [
        ({"max_video_bytes": 2048}, 413, "MOJU_MAX_VIDEO_BYTES"),
        ({"max_video_width": 64}, 413, "the limit is 64 x 1080"),
        ({"max_video_height": 48}, 413, "MOJU_MAX_VIDEO_HEIGHT"),
        ({"max_video_frames": 5}, 413, "8 frames to track, the limit is 5; cut the video"),
        ({"max_video_seconds": 0.5}, 413, "the limit is 0.5 s"),
        ({"max_points": 20}, 413, "the limit is 20 tracks (MOJU_MAX_POINTS)"),
    ],
)
def test_video_limits_are_named_in_the_refusal(
    redis_url: str, tmp_path: Path, video_files, staging: Path, limit, status, message
) -> None:
    settings = Settings(
        redis_url=redis_url, data_dir=tmp_path / "data", cleanup_interval=0, **limit
    )
    with TestClient(create_app(settings)) as client:
        response = post(client, video_files["video"].read_bytes(), video_files["mask"].read_bytes())
    assert response.status_code == status, response.text
    assert message in response.json()["detail"]
    assert stored_jobs(settings) == [] and list(staging.iterdir()) == []


@pytest.mark.parametrize(
    ("mask", "message"),
    [
        ("small", "mask mask.png is 10 x 10 pixels, the video's frames are 96 x 72"),
        ("jpeg", "is not a PNG image"),
        ("empty", "marks no pixel"),
        ("photo", "marks 100 % of the frame"),
    ],
)
def test_bad_masks_are_refused(
    client: TestClient, video_files, settings: Settings, staging: Path, mask, message
) -> None:
    if mask == "small":
        data = cv2.imencode(".png", np.full((10, 10), 255, np.uint8))[1].tobytes()
    elif mask == "jpeg":
        data = cv2.imencode(".jpg", np.full((72, 96), 255, np.uint8))[1].tobytes()
    elif mask == "photo":  # an RGB frame, non-zero everywhere, sent as the mask
        frame = np.random.default_rng(0).integers(1, 256, size=(72, 96, 3), dtype=np.uint8)
        data = cv2.imencode(".png", frame)[1].tobytes()
    else:
        data = cv2.imencode(".png", np.zeros((72, 96), np.uint8))[1].tobytes()
    response = post(client, video_files["video"].read_bytes(), data)
    assert response.status_code == 422, response.text
    assert message in response.json()["detail"]
    assert stored_jobs(settings) == [] and list(staging.iterdir()) == []


def test_a_mask_without_a_video_is_refused(client: TestClient, input_file: Path, video_files):
    files = {
        "file": (input_file.name, input_file.read_bytes(), "application/octet-stream"),
        "mask": ("mask.png", video_files["mask"].read_bytes(), "image/png"),
    }
    response = client.post("/v1/jobs", files=files)
    assert response.status_code == 422
    assert "a 'mask' goes with a video upload only" in response.json()["detail"]


def test_known_rotations_are_refused_for_a_video(client: TestClient, video_files):
    response = post(client, video_files["video"].read_bytes(), params={"rotations": "known"})
    assert response.status_code == 422
    assert "a video has no camera rotations" in response.json()["detail"]


def test_video_upload_through_the_api_runs_in_a_real_worker(
    live_api: str, worker, video_files, tmp_path: Path
) -> None:
    from service.client import MojuClient

    with MojuClient(live_api) as client:
        job = client.submit(
            video_files["video"], {"max_iter": 3}, mask=video_files["mask"], focal=150.0
        )
        assert job.input.format == "video" and job.input.video.has_mask
        assert job.input.camera.source == "focal"
        record = client.wait(job, timeout=120)
        assert record.status.value == "finished", (record.error, worker.log())
        tracks = client.download_tracks(job, tmp_path / "tracks.npz")
        with np.load(tracks, allow_pickle=False) as data:
            n_points = data["W"].shape[1]
            np.testing.assert_array_equal(data["K"], job.input.camera.K)  # tracked with it
        assert n_points == record.result.tracking.reconstructed > 0
        frames = client.download_frames_zip(job, tmp_path / "frames.zip")
        with zipfile.ZipFile(frames) as archive:
            names = archive.namelist()
            ply = PlyData.read(io.BytesIO(archive.read(names[0])))
        assert len(names) == N_FRAMES
        assert ply["vertex"].count == n_points  # shapes for every track


def test_track_overlay_of_a_dense_grid_is_not_a_blob(tmp_path: Path) -> None:
    """Tracks every 4 pixels: paths are drawn for a spread-out subset, the frame stays visible."""
    from service.track_overlay import overlay_png

    frame = np.full((120, 160, 3), 128, np.uint8)
    first_frame = tmp_path / "first.png"
    cv2.imwrite(str(first_frame), frame)
    x, y = np.meshgrid(np.arange(8, 152, 4.0), np.arange(8, 112, 4.0))
    n_frames = 12
    W = np.vstack([np.vstack([x.ravel() + f, y.ravel() + 0.5 * f]) for f in range(n_frames)])
    tracks = tmp_path / "tracks.npz"
    np.savez(tracks, W=W)
    drawn = cv2.imdecode(np.frombuffer(overlay_png(first_frame, tracks), np.uint8), 1)
    green = np.all(drawn == [80, 220, 80], axis=2) | (drawn[:, :, 1] > 150)
    changed = np.any(drawn != frame, axis=2)
    assert 0 < green.mean() < 0.25, green.mean()
    assert changed.mean() < 0.5, changed.mean()
    ends = W[-2:].T.round().astype(int)  # every track still gets its red end dot
    assert np.all(drawn[ends[:, 1], ends[:, 0]] == [40, 40, 240])
