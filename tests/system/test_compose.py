"""Docker cannot run here, so check the compose file against the code: every command is a real `fringelab`
subcommand and every FRINGELAB_ variable is a real setting."""

from __future__ import annotations

from pathlib import Path

import yaml

from backend.cli import build_parser
from fringelab.core.settings import settings_table

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
SERVICES = COMPOSE["services"]


def _fringelab_commands() -> list[list[str]]:
    commands = []
    for service in SERVICES.values():
        for argv in (service.get("command"), service.get("healthcheck", {}).get("test", [None])[1:]):
            if argv and argv[0] == "fringelab":
                commands.append(argv[1:])
    return commands


def test_the_lab_stack_has_its_parts():
    assert {"redis", "postgres", "api", "worker"} <= set(SERVICES)
    assert "appendonly" in " ".join(SERVICES["redis"]["command"])  # jobs survive a Redis restart
    assert SERVICES["api"]["volumes"] == SERVICES["worker"]["volumes"] == ["data:/data"]
    for name in SERVICES:
        assert "healthcheck" in SERVICES[name], f"{name} has no healthcheck"
    assert SERVICES["api"]["environment"]["FRINGELAB_AUTH_ENABLED"] == "true"  # a shared server needs logins
    assert "ports" not in SERVICES["worker"]  # scalable with --scale worker=N
    assert "container_name" not in SERVICES["worker"]


def test_every_command_is_a_real_subcommand():
    parser = build_parser()
    commands = _fringelab_commands()
    assert ["api"] in commands and ["worker"] in commands
    for argv in commands:
        assert callable(parser.parse_args(argv).handler), argv


def test_every_variable_is_a_real_setting():
    known = {variable for variable, _, _ in settings_table()}
    for name, service in SERVICES.items():
        for variable in service.get("environment", {}):
            if variable.startswith("FRINGELAB_"):
                assert variable in known, f"{name} sets unknown {variable}"


def test_dockerfile_copies_every_package():
    dockerfile = (ROOT / "Dockerfile").read_text()
    for directory in ("backend", "worker", "frontend"):
        assert f"COPY {directory} " in dockerfile
