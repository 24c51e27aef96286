"""The exported OpenAPI document matches the app and documents every endpoint."""

from __future__ import annotations

import json

from service.openapi import DEFAULT_PATH, main, openapi_document, render

EXPECTED_OPERATIONS = {
    ("post", "/v1/jobs"): "create_job",
    ("get", "/v1/jobs"): "list_jobs",
    ("get", "/v1/jobs/{job_id}"): "get_job",
    ("delete", "/v1/jobs/{job_id}"): "delete_job",
    ("get", "/v1/jobs/{job_id}/events"): "stream_job_events",
    ("get", "/v1/jobs/{job_id}/result"): "download_result",
    ("get", "/v1/jobs/{job_id}/frames/{frame}.ply"): "download_frame_ply",
    ("get", "/v1/jobs/{job_id}/frames.zip"): "download_frames_zip",
    ("get", "/v1/jobs/{job_id}/metrics"): "get_job_metrics",
    ("get", "/v1/jobs/{job_id}/tracks.npz"): "download_tracks",
    ("get", "/v1/jobs/{job_id}/first-frame.png"): "download_first_frame",
    ("get", "/v1/jobs/{job_id}/viewer-data"): "get_viewer_data",
    ("get", "/v1/jobs/{job_id}/viewer-data/frames/{frame}"): "get_viewer_frame",
    ("get", "/healthz"): "health",
    ("get", "/readyz"): "ready",
}


def test_exported_file_matches_the_app() -> None:
    on_disk = json.loads(DEFAULT_PATH.read_text())
    assert on_disk == openapi_document(), "run: python -m service.openapi"
    assert DEFAULT_PATH.read_text() == render(on_disk)


def test_check_mode_reports_a_stale_file(tmp_path, capsys) -> None:
    stale = tmp_path / "openapi.json"
    stale.write_text("{}\n")
    assert main(["--check", "--output", str(stale)]) == 1
    assert "out of date" in capsys.readouterr().out
    assert main(["--output", str(stale)]) == 0
    assert main(["--check", "--output", str(stale)]) == 0


def test_every_endpoint_is_documented_with_a_stable_operation_id() -> None:
    document = openapi_document()
    found = {
        (method, path): operation["operationId"]
        for path, operations in document["paths"].items()
        for method, operation in operations.items()
    }
    assert found == EXPECTED_OPERATIONS
    for path, operations in document["paths"].items():
        for method, operation in operations.items():
            where = f"{method.upper()} {path}"
            assert operation["summary"], where
            assert len(operation["description"]) > 40, where
            assert "curl" in operation["description"], f"{where} lacks an example"
            for status, response in operation["responses"].items():
                assert response["description"], f"{where} {status}"
                if status.startswith(("4", "5")):
                    schema = response["content"]["application/json"]["schema"]
                    assert schema == {"$ref": "#/components/schemas/ErrorBody"}, where


def test_parameters_schema_is_the_solver_schema() -> None:
    from moju_core.params import SolverParams

    schemas = openapi_document()["components"]["schemas"]
    assert set(schemas["SolverParams"]["properties"]) == set(SolverParams.model_fields)
    assert schemas["SolverParams"]["additionalProperties"] is False
    body = openapi_document()["paths"]["/v1/jobs"]["post"]["requestBody"]["content"]
    assert set(body) == {"multipart/form-data", "application/json"}
    assert body["application/json"]["schema"] == {"$ref": "#/components/schemas/TracksBody"}
    assert "example" in json.dumps(body["application/json"])
