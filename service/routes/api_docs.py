"""Browsable API docs at ``/docs``: Swagger UI served by the API itself, not from a CDN.

FastAPI's default ``/docs`` page loads Swagger UI's script and style from a public CDN, so it
stays blank on a machine without internet access, while the rest of the service (the web
page, plotly.js) needs none. Swagger UI's files come instead from the ``swagger-ui-py``
package (installed with the service extra; it ships Swagger UI 5, which reads the OpenAPI
3.1 document FastAPI writes) and are served under ``/docs/<name>``. They are found without
importing that package: the API process needs the files, not its Python code.
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

from fastapi import APIRouter, HTTPException
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse

__all__ = ["ASSET_NAMES", "router", "swagger_ui_dir"]

#: The files of Swagger UI that the page loads, served under ``/docs/<name>``.
ASSET_NAMES = ("swagger-ui-bundle.js", "swagger-ui.css", "favicon-32x32.png")

router = APIRouter(include_in_schema=False)


@functools.cache
def swagger_ui_dir() -> Path | None:
    """The folder of Swagger UI's files inside the installed ``swagger-ui-py``, or None."""
    spec = importlib.util.find_spec("swagger_ui")
    if spec is None or not spec.submodule_search_locations:
        return None
    folder = Path(spec.submodule_search_locations[0]) / "static"
    return folder if (folder / ASSET_NAMES[0]).is_file() else None


def _missing() -> HTTPException:
    return HTTPException(
        503, "the API docs need the swagger-ui-py package: pip install 'moju[service]'"
    )


@router.get("/docs")
async def docs_page() -> HTMLResponse:
    """Swagger UI on ``/openapi.json``, every file from this server."""
    if swagger_ui_dir() is None:
        raise _missing()
    return get_swagger_ui_html(
        openapi_url="/openapi.json",
        title="MoJu reconstruction service: API docs",
        swagger_js_url="/docs/swagger-ui-bundle.js",
        swagger_css_url="/docs/swagger-ui.css",
        swagger_favicon_url="/docs/favicon-32x32.png",
        oauth2_redirect_url=None,
    )


@router.get("/docs/{name}")
async def docs_file(name: str) -> FileResponse:
    """One of Swagger UI's files; only the names in :data:`ASSET_NAMES` are served."""
    if name not in ASSET_NAMES:
        raise HTTPException(
            404, f"no file /docs/{name}; the docs' files are {', '.join(ASSET_NAMES)}"
        )
    folder = swagger_ui_dir()
    if folder is None:
        raise _missing()
    return FileResponse(folder / name)
