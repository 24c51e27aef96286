"""docs/service.md keeps up with the code: every setting and every endpoint is described."""

from __future__ import annotations

import re
from pathlib import Path

from service.openapi import openapi_document
from service.settings import Settings

GUIDE = (Path(__file__).resolve().parents[2] / "docs" / "service.md").read_text()


def test_every_setting_is_in_the_settings_table() -> None:
    table = {match.group(1) for match in re.finditer(r"^\| `(MOJU_[A-Z_]+)` \|", GUIDE, re.M)}
    assert table == {f"MOJU_{name.upper()}" for name in Settings.model_fields}


def test_every_endpoint_is_in_the_guide() -> None:
    for path in openapi_document()["paths"]:
        shown = path.replace("{job_id}", "{id}").replace("{frame}", "{f}")
        assert shown in GUIDE, path
