"""Export the OpenAPI document of the API to ``openapi/openapi.json``.

    python -m service.openapi            # (re)write the file
    python -m service.openapi --check    # exit 1 when the file is out of date

``tests/service/test_service_openapi.py`` fails when the app and the file disagree.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from service.app import create_app
from service.settings import Settings

DEFAULT_PATH = Path(__file__).resolve().parents[1] / "openapi" / "openapi.json"


def openapi_document() -> dict[str, Any]:
    """The app's OpenAPI document (no Redis needed: the lifespan does not run)."""
    return create_app(Settings(redis_url=None)).openapi()


def render(document: dict[str, Any]) -> str:
    """The file's exact text: stable key order from the app, two-space indent, final newline."""
    return json.dumps(document, indent=2, ensure_ascii=False) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only compare, do not write")
    parser.add_argument("--output", type=Path, default=DEFAULT_PATH, help="file to write")
    arguments = parser.parse_args(argv)
    text = render(openapi_document())
    if arguments.check:
        current = arguments.output.read_text() if arguments.output.is_file() else ""
        if current != text:
            print(f"{arguments.output} is out of date: run python -m service.openapi")
            return 1
        print(f"{arguments.output} is up to date")
        return 0
    arguments.output.parent.mkdir(parents=True, exist_ok=True)
    arguments.output.write_text(text)
    print(f"wrote {arguments.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
