"""The camera fields of a submission: 'focal' or 'intrinsics', with a video or a tracks file.

The video is the tiny render of the rolling paper that the video tests use (96 x 72 pixels,
8 frames); its tracks, written as ``moju track`` writes them (with a frame size, and K when
given), are the tracks-file input. Jobs run to their end in this process through the worker's
job function (``worker.jobs.execute``) with the real tracker and solver (max_iter 3).
"""

from __future__ import annotations

import dataclasses
import io
import json
import tempfile
import warnings
from pathlib import Path
from uuid import UUID

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from numpy.testing import assert_allclose
from redis import Redis

from moju_core.cameras.intrinsics import MAX_INTRINSICS_BYTES, Intrinsics
from moju_core.footage.render import render_sequence, write_video
from moju_core.footage.tracking import solvable_tracks, track_video, write_tracks
from moju_core.io import read_measurements, read_result
from service.settings import Settings
from worker.jobs import execute

N_FRAMES, SIZE = 8, (96, 72)
PARAMS = {"max_iter": 3, "seed": 1}
FOCAL = 150.0
#: K of the 'intrinsics' field, and the one the tracks file carries (they differ).
GIVEN_K = [[140.0, 0.0, 50.0], [0.0, 145.0, 30.0], [0.0, 0.0, 1.0]]
FILE_K = Intrinsics.from_focal(300.0, SIZE).K.tolist()
K_TEXT = "# the camera\n140, 0, 50\n0 145 30\n0, 0, 1\n"


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> dict[str, Path]:
    """The video, its mask, and its tracks as npz without K and with FILE_K."""
    directory = tmp_path_factory.mktemp("clip")
    rendered = render_sequence("paper", width=SIZE[0], height=SIZE[1], n_frames=N_FRAMES)
    video = write_video(directory / "paper.mp4", rendered.frames)
    mask = directory / "mask.png"
    cv2.imwrite(str(mask), rendered.mask.astype(np.uint8) * 255)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracks seen once are left out, with a warning
        tracks = solvable_tracks(track_video(video, mask=mask))
    write_tracks(directory / "tracks.npz", tracks)
    with_k = dataclasses.replace(tracks, intrinsics=Intrinsics(np.array(FILE_K), "given"))
    write_tracks(directory / "tracks_k.npz", with_k)
    return {
        "video": video,
        "mask": mask,
        "tracks": directory / "tracks.npz",
        "tracks_k": directory / "tracks_k.npz",
    }


@pytest.fixture
def staging(tmp_path, monkeypatch) -> Path:
    """The temporary directory uploads are staged in, to check that nothing is left."""
    directory = tmp_path / "staging"
    directory.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(directory))
    return directory


def post(client: TestClient, path: Path, *, mask: Path | None = None, **camera):
    """Upload ``path``; ``camera`` holds 'focal' (text) and/or 'intrinsics' (text, or bytes
    sent as a file part)."""
    files = {"file": (path.name, path.read_bytes(), "application/octet-stream")}
    if mask is not None:
        files["mask"] = ("mask.png", mask.read_bytes(), "image/png")
    data = {"params": json.dumps(PARAMS)}
    for name, value in camera.items():
        if isinstance(value, bytes):
            files[name] = ("K.txt", value, "text/plain")
        else:
            data[name] = value
    return client.post("/v1/jobs", files=files, data=data)


def run(client: TestClient, settings: Settings, job_id: str) -> dict:
    """Run the job in this process; the finished job resource."""
    services = client.app.state.services
    outcome = execute(UUID(job_id), services.store, services.storage, settings)
    assert outcome["status"] == "finished", outcome
    return client.get(f"/v1/jobs/{job_id}").json()


def stored(settings: Settings, job_id: str, name: str) -> Path:
    return settings.data_dir / "jobs" / job_id / name


def test_a_video_with_focal_is_tracked_and_solved_with_that_camera(
    client: TestClient, settings: Settings, clip, staging: Path
) -> None:
    expected = Intrinsics.from_focal(FOCAL, SIZE).K.tolist()
    response = post(client, clip["video"], mask=clip["mask"], focal=f" {FOCAL:g} ")
    assert response.status_code == 202, response.text
    job = response.json()
    assert job["input"]["camera"] == {"K": expected, "source": "focal"}
    assert list(staging.iterdir()) == []

    finished = run(client, settings, job["id"])
    assert finished["input"]["camera"] == {"K": expected, "source": "focal"}
    tracks = client.get(f"/v1/jobs/{job['id']}/tracks.npz")
    with np.load(io.BytesIO(tracks.content), allow_pickle=False) as data:
        assert list(data["frame_size"]) == list(SIZE)
        assert_allclose(data["K"], expected)
    result = read_result(stored(settings, job["id"], "result.h5"))
    assert result.metadata["intrinsics"] == {"K": expected, "origin": "focal"}


def test_a_video_without_a_camera_gets_the_default_of_its_frame_size(
    client: TestClient, clip
) -> None:
    job = post(client, clip["video"], mask=clip["mask"]).json()
    default = Intrinsics.default_for(SIZE).K.tolist()
    assert default[0][0] == 1.2 * max(SIZE)
    assert job["input"]["camera"] == {"K": default, "source": "default"}


def test_a_default_camera_job_records_the_camera_its_solve_used(
    client: TestClient, settings: Settings, clip
) -> None:
    # The solve estimates the default camera's focal length from the tracks; the result's
    # metadata says which focal length it used and where it came from, as the plan does.
    job = post(client, clip["video"], mask=clip["mask"]).json()
    finished = run(client, settings, job["id"])
    assert finished["input"]["camera"]["source"] == "default"  # what was asked for
    result = read_result(stored(settings, job["id"], "result.h5"))
    plan = result.diagnostics.plan
    assert plan.focal_origin in ("default", "estimated")
    used = Intrinsics.default_for(SIZE).with_focal(plan.focal_px, plan.focal_origin)
    assert result.metadata["intrinsics"] == used.to_metadata()


def test_a_video_with_intrinsics_keeps_the_given_matrix(client: TestClient, clip) -> None:
    job = post(client, clip["video"], intrinsics=K_TEXT.encode()).json()
    assert job["input"]["camera"] == {"K": GIVEN_K, "source": "intrinsics"}


def test_the_intrinsics_field_replaces_the_k_of_a_tracks_file(
    client: TestClient, settings: Settings, clip
) -> None:
    response = post(client, clip["tracks_k"], intrinsics=K_TEXT)
    assert response.status_code == 202, response.text
    job_id = response.json()["id"]
    assert response.json()["input"]["camera"] == {"K": GIVEN_K, "source": "intrinsics"}
    solver_input = read_measurements(stored(settings, job_id, "input.npz"))
    assert_allclose(solver_input.intrinsics.K, GIVEN_K)

    finished = run(client, settings, job_id)
    assert finished["input"]["camera"]["K"] == GIVEN_K
    result = read_result(stored(settings, job_id, "result.h5"))
    assert result.metadata["intrinsics"] == {"K": GIVEN_K, "origin": "given"}


def test_a_tracks_file_keeps_its_own_camera_without_the_fields(
    client: TestClient, clip, input_file: Path
) -> None:
    own = post(client, clip["tracks_k"]).json()["input"]["camera"]
    assert own == {"K": FILE_K, "source": "file"}
    default = post(client, clip["tracks"]).json()["input"]["camera"]
    assert default == {"K": Intrinsics.default_for(SIZE).K.tolist(), "source": "default"}
    assert post(client, input_file).json()["input"]["camera"] is None  # no frame size


def test_focal_with_a_tracks_file_needs_its_frame_size(
    client: TestClient, settings: Settings, clip, input_file: Path
) -> None:
    job = post(client, clip["tracks_k"], focal="200").json()
    assert job["input"]["camera"] == {
        "K": Intrinsics.from_focal(200.0, SIZE).K.tolist(), "source": "focal",
    }  # fmt: skip
    refused = post(client, input_file, focal="200")
    assert refused.status_code == 422
    assert refused.json()["detail"] == (
        "the 'focal' field needs the frame size to put the principal point at the image "
        "centre, and the uploaded file has no frame_size; send the full matrix K in the "
        "'intrinsics' field instead, or add frame_size = (width, height) to the file"
    )
    assert client.get("/v1/jobs").json()["total"] == 1


BAD_CAMERAS = [
    ({"focal": "-5"}, "the 'focal' field: the focal length must be a positive number of pixels"),
    ({"focal": "0"}, "must be a positive number of pixels, got 0.0"),
    ({"focal": "nan"}, "must be a positive number of pixels, got nan"),
    ({"focal": "inf"}, "must be a positive number of pixels"),
    ({"focal": "wide"}, "the 'focal' field 'wide' is not a number; give a number of pixels"),
    ({"focal": "1" * 100}, "the 'focal' field is 100 characters long"),
    ({"focal": b"800"}, "the 'focal' field must be text"),
    ({"intrinsics": "1 0 2\n0 1 3\n"}, "the 'intrinsics' field holds 2 row(s) of [3] numbers"),
    ({"intrinsics": "1 0 2 4\n0 1 3\n0 0 1"}, "write K as three lines of three numbers"),
    ({"intrinsics": "100 0 50\n3 100 40\n0 0 1"}, "the 'intrinsics' field[1, 0] is 3, not 0"),
    ({"intrinsics": "100 0 50\n0 100 40\n0 0 2"}, "is [0.0, 0.0, 2.0], not [0, 0, 1]"),
    ({"intrinsics": "-100 0 50\n0 100 40\n0 0 1"}, "both must be positive"),
    ({"intrinsics": "nan 0 50\n0 100 40\n0 0 1"}, "holds NaN or infinite values"),
    ({"intrinsics": "fx 0 50\n0 100 40\n0 0 1"}, "the line 'fx 0 50' is not a row of numbers"),
    ({"intrinsics": b"\xff\xfe\x00"}, "the 'intrinsics' field is not a text file"),
    ({"intrinsics": b"#" * (MAX_INTRINSICS_BYTES + 1)}, "is larger than 64 KiB"),
    ({"intrinsics": "#" * (MAX_INTRINSICS_BYTES + 1)}, "is larger than 64 KiB"),
    ({"focal": "800", "intrinsics": K_TEXT}, "the 'focal' and 'intrinsics' fields both give"),
]


@pytest.mark.parametrize("upload", ["video", "tracks_k"])
@pytest.mark.parametrize(("camera", "message"), BAD_CAMERAS)
def test_bad_cameras_are_refused_and_nothing_is_kept(
    client: TestClient, settings: Settings, redis_client: Redis, clip, staging: Path,
    upload, camera, message,
) -> None:  # fmt: skip
    response = post(client, clip[upload], **camera)
    assert response.status_code == 422, response.text
    assert message in response.json()["detail"]
    assert list((settings.data_dir / "jobs").iterdir()) == []
    assert list(staging.iterdir()) == []
    assert redis_client.llen(f"rq:queue:{settings.queue_name}") == 0
    assert client.get("/v1/jobs").json()["total"] == 0


def test_both_fields_are_refused_with_what_to_do(client: TestClient, clip) -> None:
    response = post(client, clip["video"], focal="800", intrinsics=K_TEXT.encode())
    assert response.status_code == 422
    assert response.json()["detail"] == (
        "the 'focal' and 'intrinsics' fields both give the camera; send one of them: "
        "'intrinsics' for the full matrix K, or 'focal' for a focal length in pixels with the "
        "principal point at the image centre"
    )


def test_blank_fields_are_no_camera(client: TestClient, clip) -> None:
    """What a browser sends for fields left empty: an empty text, a nameless empty file."""
    files = {
        "file": ("tracks.npz", clip["tracks_k"].read_bytes()),
        "intrinsics": ("", b"", "application/octet-stream"),
    }
    response = client.post("/v1/jobs", files=files, data={"focal": " "})
    assert response.status_code == 202, response.text
    assert response.json()["input"]["camera"]["source"] == "file"
