"""The web page's files and the viewer-data endpoints, without a browser.

Finished jobs are made by running the worker's job function (``worker.jobs.execute``) in the
test process on a job submitted through the API, so no worker process is needed.
"""

from __future__ import annotations

import json
import re
import uuid
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from numpy.testing import assert_allclose
from plotly.offline import get_plotlyjs

from moju_core.io import read_result
from service.camera_fields import CAMERA_FIELDS
from service.routes.viewer import PAGE_FILES, STATIC_DIR, page_file
from service.settings import Settings
from worker.jobs import execute

PARAMS = {"max_iter": 40, "seed": 3}


def finished_job(client: TestClient, settings: Settings, path: Path, **params) -> str:
    """Submit ``path`` and run its job to the end in this process; the job id."""
    files = {"file": (path.name, path.read_bytes())}
    response = client.post("/v1/jobs", files=files, data={"params": json.dumps(params)})
    assert response.status_code == 202, response.text
    job_id = response.json()["id"]
    services = client.app.state.services
    outcome = execute(uuid.UUID(job_id), services.store, services.storage, settings)
    assert outcome["status"] == "finished", outcome
    return job_id


def stored_result(settings: Settings, job_id: str):
    return read_result(settings.data_dir / "jobs" / job_id / "result.h5")


def test_page_and_its_files_are_served(client: TestClient) -> None:
    page = client.get("/")
    assert page.status_code == 200
    assert page.headers["content-type"].startswith("text/html")
    assert '<form id="submit-form"' in page.text
    assert page.text == (STATIC_DIR / "index.html").read_text()

    types = {".html": "text/html", ".js": "text/javascript", ".css": "text/css"}
    for name in PAGE_FILES:
        response = client.get(f"/static/{name}")
        assert response.status_code == 200, name
        assert response.headers["content-type"].startswith(types[Path(name).suffix]), name
        assert response.content == page_file(name).read_bytes()

    plotly = client.get("/static/plotly.min.js")
    assert plotly.status_code == 200
    assert plotly.headers["content-type"].startswith("text/javascript")
    assert plotly.content == get_plotlyjs().encode()

    missing = client.get("/static/nothing.js")
    assert missing.status_code == 404
    assert missing.json()["detail"] == (
        "no file /static/nothing.js; the page's files are index.html, app.js, viewer.js, style.css"
    )
    for name in ("..%2Fapp.py", "%2E%2E%2Froutes%2Fviewer.py", "plotly.min.js%00"):
        assert client.get(f"/static/{name}").status_code == 404, name


def test_page_refers_to_nothing_outside_the_service() -> None:
    """The page must work offline: no script, style, font or request from another host."""
    external = re.compile(
        r"""(?:src|href)\s*=\s*["'](?:https?:)?//|url\(\s*["']?(?:https?:)?//|"""
        r"""@import|fetch\(\s*["'`](?:https?:)?//|EventSource\(\s*["'`](?:https?:)?//""",
        re.IGNORECASE,
    )
    for name in PAGE_FILES:
        text = page_file(name).read_text()
        assert not external.search(text), f"{name}: {external.search(text).group(0)}"
    index = (STATIC_DIR / "index.html").read_text()
    scripts = re.findall(r'<script src="([^"]+)"', index)
    assert scripts == ["/static/plotly.min.js", "/static/viewer.js", "/static/app.js"]


def test_the_form_sends_the_camera_fields() -> None:
    """The submit form has the optional camera inputs, and its script sends them under the
    API's field names, only when filled in (the API refuses both together)."""
    index = (STATIC_DIR / "index.html").read_text()
    assert '<input id="focal" name="focal" type="number" min="0" step="any"' in index
    assert '<input id="intrinsics" name="intrinsics" type="file"' in index
    script = (STATIC_DIR / "app.js").read_text()
    for name in CAMERA_FIELDS:
        assert f'$("#{name}")' in script, name
    assert 'if (focal !== "") {\n      body.append("focal", focal);' in script
    assert (
        'if (intrinsics) {\n      body.append("intrinsics", intrinsics, intrinsics.name);' in script
    )
    assert "job.input.camera" in script  # the job list shows the camera


def test_viewer_data_of_a_finished_job(
    client: TestClient, settings: Settings, input_file: Path, small_sequence
) -> None:
    job_id = finished_job(client, settings, input_file, **PARAMS)
    result = stored_result(settings, job_id)

    response = client.get(f"/v1/jobs/{job_id}/viewer-data")
    assert response.status_code == 200, response.text
    data = response.json()
    assert data["job_id"] == job_id
    assert (data["frames"], data["points"], data["shown_points"]) == (10, 300, 300)
    assert data["decimated"] is False and data["point_indices"] is None
    assert data["labels"] == result.labels.tolist()
    assert data["groups"] == len(np.unique(result.labels))
    assert data["faces"] == small_sequence.faces.tolist()
    red, green, blue = small_sequence.colors[7, :3]
    assert data["colors"][7] == f"#{red:02x}{green:02x}{blue:02x}"
    assert data["n_iter"] == result.n_iter == 40
    assert data["stop_reason"] == result.stop_reason
    assert set(data["history"]) == set(result.history)
    assert_allclose(data["history"]["gap"], result.history["gap"])
    assert_allclose(data["rotations"], result.rotations, atol=1e-6)

    # The axis ranges hold every frame's points, with a margin.
    for axis, column in (("x", 0), ("y", 1), ("z", 2)):
        low, high = data["ranges"][axis]
        assert low < result.shapes[:, :, column].min() <= result.shapes[:, :, column].max() < high

    # A frame: the stored shape, and the depth along the frame's optical axis r1 x r2.
    frame = client.get(f"/v1/jobs/{job_id}/viewer-data/frames/3").json()
    assert frame["frame"] == 3
    points = np.column_stack([frame["x"], frame["y"], frame["z"]])
    tolerance = 1e-4 * np.abs(result.shapes[3]).max()
    assert_allclose(points, result.shapes[3], rtol=0, atol=tolerance)
    r1, r2 = result.rotations[3]
    assert_allclose(frame["depth"], result.shapes[3] @ np.cross(r1, r2), rtol=0, atol=tolerance)
    low, high = data["ranges"]["depth"]
    assert low < min(frame["depth"]) and max(frame["depth"]) < high


def test_viewer_data_decimates_to_max_points(
    client: TestClient, settings: Settings, input_file: Path
) -> None:
    job_id = finished_job(client, settings, input_file, **PARAMS)
    result = stored_result(settings, job_id)

    data = client.get(f"/v1/jobs/{job_id}/viewer-data", params={"max_points": 50}).json()
    assert (data["points"], data["shown_points"], data["decimated"]) == (300, 50, True)
    indices = data["point_indices"]
    assert len(indices) == 50 and indices == sorted(set(indices))
    assert 0 <= indices[0] and indices[-1] < 300
    assert data["labels"] == result.labels[indices].tolist()
    assert data["faces"] is None  # a random subset keeps too few whole triangles
    assert len(data["colors"]) == 50

    frame = client.get(f"/v1/jobs/{job_id}/viewer-data/frames/9", params={"max_points": 50}).json()
    tolerance = 1e-4 * np.abs(result.shapes[9]).max()
    assert_allclose(frame["x"], result.shapes[9, indices, 0], rtol=0, atol=tolerance)
    assert_allclose(frame["z"], result.shapes[9, indices, 2], rtol=0, atol=tolerance)
    # The same subset on every request.
    again = client.get(f"/v1/jobs/{job_id}/viewer-data", params={"max_points": 50}).json()
    assert again["point_indices"] == indices


def test_viewer_data_errors(client: TestClient, settings: Settings, input_file: Path) -> None:
    files = {"file": (input_file.name, input_file.read_bytes())}
    queued = client.post("/v1/jobs", files=files).json()["id"]
    unfinished = client.get(f"/v1/jobs/{queued}/viewer-data")
    assert unfinished.status_code == 409
    assert unfinished.json()["detail"].startswith(f"job {queued} is queued;")
    assert client.get(f"/v1/jobs/{queued}/viewer-data/frames/0").status_code == 409

    missing = uuid.uuid4()
    assert client.get(f"/v1/jobs/{missing}/viewer-data").status_code == 404

    job_id = finished_job(client, settings, input_file, **PARAMS)
    beyond = client.get(f"/v1/jobs/{job_id}/viewer-data/frames/10")
    assert beyond.status_code == 404
    assert beyond.json()["detail"] == f"job {job_id} has 10 frames (0..9); there is no frame 10"
    for bad in (0, 20_001):
        refused = client.get(f"/v1/jobs/{job_id}/viewer-data", params={"max_points": bad})
        assert refused.status_code == 422
        assert "max_points" in refused.json()["detail"]

    # Deleted after it finished: the files are gone with the record.
    assert client.delete(f"/v1/jobs/{job_id}").status_code == 204
    assert client.get(f"/v1/jobs/{job_id}/viewer-data").status_code == 404


def test_page_files_are_package_data() -> None:
    """pyproject ships every page file with its package (the page of an installed service)."""
    tomllib = pytest.importorskip("tomllib", reason="tomllib needs Python 3.11")
    root = STATIC_DIR.parents[1]
    pyproject = tomllib.loads((root / "pyproject.toml").read_text())
    package_data = pyproject["tool"]["setuptools"]["package-data"]
    for name in PAGE_FILES:
        relative = page_file(name).relative_to(root)
        patterns = package_data[relative.parts[0]]
        assert any(Path(*relative.parts[1:]).match(pattern) for pattern in patterns), name
