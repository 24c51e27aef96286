"""``/docs``: Swagger UI from the API itself, so that the docs work without internet access."""

from __future__ import annotations

import re

from fastapi.testclient import TestClient

from service.routes import api_docs


def test_docs_page_loads_every_file_from_this_server(client: TestClient) -> None:
    page = client.get("/docs")
    assert page.status_code == 200
    assert page.headers["content-type"].startswith("text/html")
    # Nothing from another host: every src and href is a path on this server.
    references = re.findall(r"""(?:src|href)\s*=\s*["']([^"']+)["']""", page.text)
    assert references and all(ref.startswith("/docs/") for ref in references), references
    assert not re.search(r"https?://", page.text)
    assert "url: '/openapi.json'" in page.text
    types = {".js": "text/javascript", ".css": "text/css", ".png": "image/png"}
    for reference in references:
        response = client.get(reference)
        assert response.status_code == 200, reference
        suffix = reference[reference.rindex(".") :]
        assert response.headers["content-type"].startswith(types[suffix]), reference
    assert client.get("/openapi.json").status_code == 200


def test_the_bundled_swagger_ui_reads_openapi_3_1(client: TestClient) -> None:
    """FastAPI writes OpenAPI 3.1; Swagger UI reads 3.1 from its version 5 on."""
    assert client.get("/openapi.json").json()["openapi"].startswith("3.1")
    bundle = (api_docs.swagger_ui_dir() / "swagger-ui-bundle.js").read_text(encoding="utf-8")
    versions = {int(major) for major in re.findall(r'"(\d+)\.\d+\.\d+"', bundle)}
    assert 5 in versions
    assert "OpenAPI 3.1" in bundle or "3.1.0" in bundle


def test_only_the_listed_files_are_served(client: TestClient) -> None:
    missing = client.get("/docs/nothing.js")
    assert missing.status_code == 404
    assert "the docs' files are swagger-ui-bundle.js" in missing.json()["detail"]
    for name in ("..%2Fapi_docs.py", "%2E%2E%2Fstatic%2Fapp.js", "swagger-ui.css%00"):
        assert client.get(f"/docs/{name}").status_code == 404, name
    assert client.get("/redoc").status_code == 404  # it would load ReDoc from a CDN


def test_without_swagger_ui_installed_the_docs_say_what_to_install(
    client: TestClient, monkeypatch
) -> None:
    monkeypatch.setattr(api_docs, "swagger_ui_dir", lambda: None)
    response = client.get("/docs")
    assert response.status_code == 503
    assert "pip install 'moju[service]'" in response.json()["detail"]
