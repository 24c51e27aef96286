"""POST /v1/jobs: what is accepted, what is refused (and with which message)."""

from __future__ import annotations

import asyncio
import io
import json
from pathlib import Path
from uuid import UUID

import h5py
import numpy as np
import pytest
from fastapi.testclient import TestClient
from redis import Redis
from rq.job import Job as RQJob

from moju_core.io import Measurements, read_measurements, write_measurements
from moju_core.params import SolverParams
from service.app import create_app
from service.settings import Settings
from service.storage import INPUT_NAME


def upload(client: TestClient, path: Path, params: dict | str | None = None, name=None):
    data = {} if params is None else {"params": params if isinstance(params, str) else
                                      json.dumps(params)}  # fmt: skip
    files = {"file": (name or path.name, path.read_bytes(), "application/octet-stream")}
    return client.post("/v1/jobs", files=files, data=data)


def test_npz_upload_is_accepted_stored_and_queued(
    client: TestClient, input_file: Path, settings: Settings, redis_client: Redis
) -> None:
    response = upload(client, input_file, {"max_iter": 40, "seed": 3})

    assert response.status_code == 202, response.text
    job = response.json()
    assert response.headers["location"] == f"/v1/jobs/{job['id']}"
    assert UUID(job["id"]).version == 4
    assert job["status"] == "queued"
    assert job["parameters"]["max_iter"] == 40 and job["parameters"]["seed"] == 3
    # The rotation method is recorded resolved: the file has R, so unset means "known".
    expected = SolverParams(max_iter=40, seed=3, rotations="known")
    assert job["parameters"] == expected.model_dump(mode="json")
    assert job["input"] == {
        "frames": 10,
        "points": 300,
        "format": "npz",
        "filename": "face_small.npz",
        "size_bytes": input_file.stat().st_size,
        "has_rotations": True,
        "has_ground_truth": True,
        "has_faces": True,
        "has_colors": True,
        "observed_fraction": 1.0,
        "video": None,
        "camera": None,  # no K, no frame size: orthographic tracks
    }
    assert job["started_at"] is None and job["progress"] is None and job["error"] is None
    assert job["links"]["metrics"] == f"/v1/jobs/{job['id']}/metrics"
    # The normalised input is in storage, identical to the upload.
    stored = read_measurements(settings.data_dir / "jobs" / job["id"] / INPUT_NAME)
    original = read_measurements(input_file)
    np.testing.assert_array_equal(stored.W, original.W)
    np.testing.assert_array_equal(stored.faces, original.faces)
    # RQ has the job under the same id, queued for the worker function.
    rq_job = RQJob.fetch(job["id"], connection=redis_client)
    assert rq_job.get_status() == "queued"
    assert rq_job.func_name == "worker.jobs.run_reconstruction"
    assert rq_job.args == (job["id"],)
    assert rq_job.timeout == settings.job_timeout
    # GET returns the same resource.
    assert client.get(f"/v1/jobs/{job['id']}").json() == job


def test_hdf5_and_csv_uploads_are_accepted(
    client: TestClient, tmp_path: Path, small_sequence
) -> None:
    measurements = Measurements(W=small_sequence.W)
    for suffix, expected in ((".h5", "h5"), (".csv", "csv")):
        path = write_measurements(tmp_path / f"tracks{suffix}", measurements)
        response = upload(client, path)
        assert response.status_code == 202, response.text
        assert response.json()["input"]["format"] == expected
        assert response.json()["input"]["points"] == 300


def test_format_is_detected_from_content_not_name(client: TestClient, input_file: Path) -> None:
    response = upload(client, input_file, name="tracks.csv")
    assert response.status_code == 202, response.text
    assert response.json()["input"]["format"] == "npz"


def test_json_tracks_are_accepted(client: TestClient, small_sequence) -> None:
    tracks = small_sequence.W.reshape(10, 2, 300).transpose(0, 2, 1)
    body = {"tracks": tracks.tolist(), "params": {"max_iter": 7}}
    response = client.post("/v1/jobs", json=body)
    assert response.status_code == 202, response.text
    job = response.json()
    assert job["input"]["format"] == "json" and job["input"]["frames"] == 10
    assert job["parameters"]["max_iter"] == 7


def test_unknown_parameter_is_named(client: TestClient, input_file: Path) -> None:
    response = upload(client, input_file, {"max_itr": 100})
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert "unknown parameter 'max_itr'" in detail
    assert "max_iter" in detail  # the list of known parameters helps fix the typo

    response = client.post("/v1/jobs", json={"tracks": [[[0, 0]] * 3] * 3, "params": {"bta": 1}})
    assert response.status_code == 422
    assert "unknown parameter 'bta'" in response.json()["detail"]


def test_invalid_parameter_value_says_what_is_allowed(client: TestClient, input_file) -> None:
    response = upload(client, input_file, {"max_iter": 0, "method": "magic"})
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert "parameter 'max_iter'" in detail and "greater than or equal to 1" in detail
    assert "parameter 'method'" in detail and "'moju'" in detail


def test_params_must_be_a_json_object(client: TestClient, input_file: Path) -> None:
    response = upload(client, input_file, "max_iter=3")
    assert response.status_code == 422
    assert "'params' field is not valid JSON" in response.json()["detail"]
    response = upload(client, input_file, "[1, 2]")
    assert response.status_code == 422
    assert "params must be a JSON object" in response.json()["detail"]


@pytest.mark.parametrize(
    ("has_rotations", "requested", "recorded"),
    [(True, None, "known"), (False, None, "auto"), (True, "auto", "auto")],
)
def test_job_record_shows_the_resolved_rotation_method(
    client: TestClient, tmp_path: Path, small_sequence, has_rotations, requested, recorded
) -> None:
    rotations = small_sequence.rotations if has_rotations else None
    path = write_measurements(
        tmp_path / "in.npz", Measurements(W=small_sequence.W, rotations=rotations)
    )
    params = {} if requested is None else {"rotations": requested}
    response = upload(client, path, params)
    assert response.status_code == 202, response.text
    assert response.json()["parameters"]["rotations"] == recorded


def test_known_rotations_need_rotations_in_the_input(
    client: TestClient, tmp_path: Path, small_sequence
) -> None:
    without_rotations = write_measurements(tmp_path / "w.npz", Measurements(W=small_sequence.W))
    response = upload(client, without_rotations, {"rotations": "known"})
    assert response.status_code == 422
    assert "rotations is 'known' but the input has no rotations" in response.json()["detail"]

    with_rotations = write_measurements(
        tmp_path / "wr.npz", Measurements(W=small_sequence.W, rotations=small_sequence.rotations)
    )
    assert upload(client, with_rotations, {"rotations": "known"}).status_code == 202


def test_pickles_are_refused(client: TestClient, tmp_path: Path) -> None:
    path = tmp_path / "pickled.npz"
    objects = np.empty((4, 5), dtype=object)
    objects[:] = 1.0
    np.savez(path, W=objects)  # numpy pickles object arrays
    response = upload(client, path)
    assert response.status_code == 422
    assert "never pickles" in response.json()["detail"]


def test_non_finite_and_misshapen_tracks_are_refused(client: TestClient, tmp_path: Path) -> None:
    W = np.random.default_rng(0).normal(size=(8, 30))
    W[3, 7] = np.nan
    np.savez(tmp_path / "nan.npz", W=W)
    response = upload(client, tmp_path / "nan.npz")
    assert response.status_code == 422
    # x NaN and y not: neither an observed nor an unobserved point.
    assert "one coordinate NaN" in response.json()["detail"]
    assert "frame 1, point 7" in response.json()["detail"]

    np.savez(tmp_path / "odd.npz", W=np.ones((7, 30)))
    response = upload(client, tmp_path / "odd.npz")
    assert response.status_code == 422
    assert "even number" in response.json()["detail"]

    response = client.post("/v1/jobs", json={"tracks": [[[0, 0], [1, 1]], [[0, 0]]]})
    assert response.status_code == 422
    assert "not a rectangular array" in response.json()["detail"]


def test_unreadable_file_is_refused(client: TestClient, tmp_path: Path) -> None:
    path = tmp_path / "garbage.h5"
    path.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\x00" * 100)
    response = upload(client, path)
    assert response.status_code == 422
    assert "could not read" in response.json()["detail"]


def test_point_and_frame_limits_answer_413(settings: Settings, input_file: Path) -> None:
    limited = settings.model_copy(update={"max_points": 200})
    with TestClient(create_app(limited)) as client:
        response = upload(client, input_file)
        assert response.status_code == 413
        assert "200 points" in response.json()["detail"]
        tracks = np.zeros((3, 250, 2)).tolist()
        response = client.post("/v1/jobs", json={"tracks": tracks})
        assert response.status_code == 413
        assert "200 points" in response.json()["detail"]


def test_memory_limit_answers_413(settings: Settings, tmp_path: Path, redis_client: Redis) -> None:
    limited = settings.model_copy(update={"worker_memory_bytes": 256 * 2**20})
    W = np.random.default_rng(0).normal(size=(2 * 300, 2000)).astype(np.float32)
    np.savez(tmp_path / "big.npz", W=W)
    with TestClient(create_app(limited)) as client:
        response = upload(client, tmp_path / "big.npz")
    assert response.status_code == 413
    assert response.json()["detail"] == (
        "300 frames x 2000 points would need about 274 MiB to solve; the limit is 256 MiB "
        "per job (MOJU_WORKER_MEMORY_BYTES): subsample the points or frames"
    )
    assert list((limited.data_dir / "jobs").iterdir()) == []
    assert redis_client.keys("*") == []


def test_worker_memory_setting_and_its_old_name(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MOJU_MAX_JOB_MEMORY_BYTES", str(2**30))
    assert Settings().worker_memory_bytes == 2**30  # the old name is still read
    monkeypatch.setenv("MOJU_WORKER_MEMORY_BYTES", str(2**31))
    assert Settings().worker_memory_bytes == 2**31  # the new name wins
    assert Settings(worker_memory_bytes=2**32).worker_memory_bytes == 2**32


def test_declared_oversized_body_is_refused_before_reading(
    settings: Settings, input_file: Path
) -> None:
    limited = settings.model_copy(update={"max_upload_bytes": 4096})
    with TestClient(create_app(limited)) as client:
        response = upload(client, input_file)
    assert response.status_code == 413
    detail = response.json()["detail"]
    assert "at most 4096 bytes" in detail and "MOJU_MAX_UPLOAD_BYTES" in detail


@pytest.mark.parametrize(
    "content_type",
    [b"application/json", b"multipart/form-data; boundary=xyz"],
)
def test_streamed_body_is_cut_at_the_limit(settings: Settings, content_type: bytes) -> None:
    """Without Content-Length the server stops reading once the limit is passed."""
    limit, chunk = 64 * 1024, 8 * 1024
    limited = settings.model_copy(update={"max_upload_bytes": limit})
    app = create_app(limited)
    delivered = 0
    sent: list[dict] = []
    # A multipart body whose file part never ends; a JSON body that never ends.
    opening = (
        b'--xyz\r\nContent-Disposition: form-data; name="file"; filename="w.npz"\r\n\r\n'
        if content_type.startswith(b"multipart")
        else b""
    )

    async def receive() -> dict:
        nonlocal delivered
        body = opening if delivered == 0 and opening else b"x" * chunk
        delivered += len(body)
        return {"type": "http.request", "body": body, "more_body": delivered < 10**8}

    async def send(message: dict) -> None:
        sent.append(message)

    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "POST",
        "scheme": "http",
        "path": "/v1/jobs",
        "raw_path": b"/v1/jobs",
        "query_string": b"",
        "root_path": "",
        "headers": [(b"content-type", content_type), (b"host", b"test")],
        "client": ("127.0.0.1", 1),
        "server": ("127.0.0.1", 80),
    }

    async def run() -> None:
        async with app.router.lifespan_context(app):
            await app(scope, receive, send)

    asyncio.run(run())
    start = next(m for m in sent if m["type"] == "http.response.start")
    body = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    assert start["status"] == 413
    assert f"at most {limit} bytes" in json.loads(body)["detail"]
    assert delivered <= limit + chunk  # never read (much) more than the limit


def test_unsupported_media_type_and_bad_forms(client: TestClient, input_file: Path) -> None:
    response = client.post("/v1/jobs", content=b"W,1,2", headers={"content-type": "text/csv"})
    assert response.status_code == 415
    assert "multipart/form-data" in response.json()["detail"]

    response = client.post("/v1/jobs", data={"params": "{}"}, files={"other": ("a", b"1")})
    assert response.status_code == 422
    assert response.json()["detail"].startswith("unexpected form field(s) 'other'")

    response = client.post("/v1/jobs", data={"params": "{}"}, files={"params": ("p", b"{}")})
    assert response.status_code == 422
    assert "the form has no 'file' field" in response.json()["detail"]

    response = client.post("/v1/jobs", data={"file": "not a file"}, files={"x": ("x", b"")})
    assert response.status_code == 422

    response = client.post("/v1/jobs", data={"file": "text"}, files={"params": ("p", b"{}")})
    assert response.status_code == 422
    assert "'file' field must be a file upload" in response.json()["detail"]

    two_files = {"file": ("a.npz", input_file.read_bytes()), "extra": ("b", b"2")}
    response = client.post("/v1/jobs", files=two_files)
    assert response.status_code == 422
    assert "unexpected form field(s) 'extra'" in response.json()["detail"]


def test_nothing_is_stored_or_queued_for_refused_input(
    client: TestClient, tmp_path: Path, settings: Settings, redis_client: Redis
) -> None:
    np.savez(tmp_path / "bad.npz", W=np.ones((3, 5)))
    assert upload(client, tmp_path / "bad.npz").status_code == 422
    assert list((settings.data_dir / "jobs").iterdir()) == []
    assert redis_client.llen(f"rq:queue:{settings.queue_name}") == 0
    assert client.get("/v1/jobs").json()["total"] == 0


def test_h5_upload_with_group_is_refused(client: TestClient, tmp_path: Path) -> None:
    path = tmp_path / "group.h5"
    with h5py.File(path, "w") as h5:
        h5.create_group("W")
    response = upload(client, path)
    assert response.status_code == 422
    assert "HDF5 group" in response.json()["detail"]


@pytest.mark.parametrize("body", [b"{", b"[]", b'"tracks"'])
def test_malformed_json_bodies(client: TestClient, body: bytes) -> None:
    response = client.post("/v1/jobs", content=body, headers={"content-type": "application/json"})
    assert response.status_code == 422
    assert response.json()["detail"].startswith("the ")


def test_csv_upload_via_file_object(client: TestClient, small_sequence) -> None:
    buffer = io.StringIO()
    buffer.write("frame,point,x,y\n")
    tracks = small_sequence.W.reshape(10, 2, 300)
    for frame in range(10):
        for point in range(300):
            buffer.write(f"{frame},{point},{tracks[frame, 0, point]},{tracks[frame, 1, point]}\n")
    files = {"file": ("tracks.csv", buffer.getvalue().encode(), "text/csv")}
    response = client.post("/v1/jobs", files=files)
    assert response.status_code == 202, response.text
    assert response.json()["input"]["format"] == "csv"
