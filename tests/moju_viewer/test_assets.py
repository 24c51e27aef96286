"""moju_viewer.assets: the viewer's files, found for the web page and for ``moju view``."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import moju_viewer
from moju_viewer.assets import ASSET_NAMES, asset_path, read_asset


def test_every_asset_is_there_and_nothing_else_is_handed_out() -> None:
    for name in ASSET_NAMES:
        assert asset_path(name).is_file(), name
        assert read_asset(name).strip(), name
    assert "MojuViewer" in read_asset("viewer.js")
    with pytest.raises(ValueError, match="no viewer file '../assets.py'"):
        asset_path("../assets.py")


def test_the_viewer_imports_nothing_of_the_service() -> None:
    """moju view must work without the service package: only moju_core and libraries."""
    for path in Path(moju_viewer.__file__).parent.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module:
                assert node.module.split(".")[0] not in ("service", "worker"), path.name
            if isinstance(node, ast.Import):
                for alias in node.names:
                    assert alias.name.split(".")[0] not in ("service", "worker"), path.name
