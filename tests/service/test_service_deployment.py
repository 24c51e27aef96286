"""docker-compose.yml and the Dockerfile name real entry points and share the data volume.

Docker itself cannot run in CI, so this checks what can go wrong without it: commands that
name scripts, modules or attributes that do not exist, a Redis without persistence, workers
that do not see the API's files.
"""

from __future__ import annotations

import importlib
import json
import re
import shlex
from pathlib import Path

import pytest
import tomllib
import yaml

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((REPO / "docker-compose.yml").read_text())


def console_scripts() -> dict[str, str]:
    with open(REPO / "pyproject.toml", "rb") as handle:
        return tomllib.load(handle)["project"]["scripts"]


def check_command(command: list[str]) -> None:
    """Fail unless ``command`` starts a console script, module or app factory that exists."""
    program, *arguments = command
    if program == "moju":
        target = console_scripts()["moju"]  # "moju_cli.main:cli"
        module_name, _, attribute = target.partition(":")
        group = getattr(importlib.import_module(module_name), attribute)
        assert arguments[0] in group.commands, f"moju has no command {arguments[0]!r}"
    elif program == "uvicorn":
        assert "--factory" in arguments, "create_app is a factory: uvicorn needs --factory"
        app_reference = next(a for a in arguments if ":" in a and not a.startswith("-"))
        module_name, _, attribute = app_reference.partition(":")
        assert callable(getattr(importlib.import_module(module_name), attribute))
    elif program == "python":
        assert arguments[0] == "-m", f"python runs a module here, not {arguments[0]!r}"
        module = importlib.import_module(arguments[1])
        assert callable(getattr(module, "main", None)), f"{arguments[1]} has no main()"
    elif program == "redis-server":
        pass  # from the redis image
    else:
        raise AssertionError(f"unknown program {program!r} in {command}")


def test_services_and_commands(compose: dict) -> None:
    services = compose["services"]
    assert set(services) == {"redis", "api", "worker"}
    for service in services.values():
        command = service["command"]
        check_command(command if isinstance(command, list) else shlex.split(command))


def test_redis_persists_to_a_volume(compose: dict) -> None:
    redis = compose["services"]["redis"]
    command = " ".join(redis["command"])
    assert "--appendonly yes" in command
    assert any(volume.endswith(":/data") for volume in redis["volumes"])
    assert "healthcheck" in redis


def test_api_and_workers_share_redis_queue_and_data(compose: dict) -> None:
    api, worker = compose["services"]["api"], compose["services"]["worker"]
    for name in ("MOJU_REDIS_URL", "MOJU_DATA_DIR", "MOJU_QUEUE_NAME"):
        assert api["environment"][name] == worker["environment"][name], name
    assert api["environment"]["MOJU_REDIS_URL"].startswith("redis://redis:")
    data_dir = api["environment"]["MOJU_DATA_DIR"]
    api_volumes = {v.split(":")[0] for v in api["volumes"] if v.endswith(f":{data_dir}")}
    worker_volumes = {v.split(":")[0] for v in worker["volumes"] if v.endswith(f":{data_dir}")}
    assert api_volumes and api_volumes == worker_volumes
    assert api_volumes <= set(compose["volumes"])
    assert worker["deploy"]["replicas"] >= 2
    assert worker["image"] == api["image"]


def test_every_setting_used_in_compose_exists() -> None:
    from service.settings import Settings

    text = (REPO / "docker-compose.yml").read_text()
    for name in set(re.findall(r"\bMOJU_[A-Z_]+\b", text)):
        assert name.removeprefix("MOJU_").lower() in Settings.model_fields, name


def test_dockerfile_copies_existing_paths_and_runs_the_api() -> None:
    lines = (REPO / "Dockerfile").read_text().splitlines()
    copies = [line.split()[1:-1] for line in lines if line.startswith("COPY ")]
    packages = {"moju_core", "moju_viewer", "moju_cli", "service", "worker"}
    assert packages <= {source for sources in copies for source in sources}
    for sources in copies:
        for source in sources:
            if source != "README.md":  # the project's README; pip needs it (pyproject readme)
                assert (REPO / source).exists(), source
    cmd = next(line for line in lines if line.startswith("CMD "))
    check_command(json.loads(cmd.removeprefix("CMD ")))
    ignored = (REPO / ".dockerignore").read_text().split()
    assert not packages & set(ignored)
