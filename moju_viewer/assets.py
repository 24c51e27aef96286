"""The files of the result viewer, shared by the service's web page and ``moju view``.

The viewer's script and style sheet live in this package's ``static/`` folder and are read
from here by both: the API serves them under ``/static/<name>``, ``moju view`` inlines them
into one HTML file. plotly.js comes from the installed ``plotly`` package.
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

__all__ = ["ASSET_DIR", "ASSET_NAMES", "asset_path", "plotly_js_path", "read_asset"]

#: Folder of the viewer's own files.
ASSET_DIR = Path(__file__).resolve().parent / "static"
#: The viewer's files: its script (``MojuViewer``) and the style sheet of every page.
ASSET_NAMES = ("viewer.js", "style.css")


def asset_path(name: str) -> Path:
    """Path of one of :data:`ASSET_NAMES`; ValueError for any other name."""
    if name not in ASSET_NAMES:
        raise ValueError(f"no viewer file {name!r}; the files are {', '.join(ASSET_NAMES)}")
    return ASSET_DIR / name


def read_asset(name: str) -> str:
    """Text of one of :data:`ASSET_NAMES` (UTF-8)."""
    return asset_path(name).read_text(encoding="utf-8")


@functools.cache
def plotly_js_path() -> Path | None:
    """``plotly.min.js`` as shipped inside the installed ``plotly`` package, or None.

    Found without importing plotly: the API process needs the file, not the Python library.
    """
    spec = importlib.util.find_spec("plotly")
    if spec is None or not spec.submodule_search_locations:
        return None
    path = Path(spec.submodule_search_locations[0]) / "package_data" / "plotly.min.js"
    return path if path.is_file() else None
