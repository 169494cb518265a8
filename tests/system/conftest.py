"""A shared lab server as people run it: `fringelab up` with accounts on, in a subprocess on a free loopback port,
with users and tokens made as the `fringelab user` / `token` commands make them. The tests talk HTTP to it only."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import pytest

from tests.support import UpProcess, add_people

PEOPLE = (("admin", True), ("ada", False), ("bob", False))


@dataclass
class LabServer:
    up: UpProcess
    tokens: dict[str, str] = field(default_factory=dict)

    @property
    def url(self) -> str:
        return self.up.base_url

    def client(self, who: str | None = None, **options: object) -> httpx.Client:
        headers = {"Authorization": f"Bearer {self.tokens[who]}"} if who else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=30, **options)  # type: ignore[arg-type]

    def cli(self, *args: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "backend.cli", *args], env=self.up.env, input=stdin,
                              capture_output=True, text=True, timeout=120)  # fmt: skip


def start_lab_server(data_dir: Path, **env: str) -> LabServer:
    up = UpProcess(data_dir, extra_env={"FRINGELAB_AUTH_ENABLED": "true", "FRINGELAB_WORKER_CONCURRENCY": "2", **env})
    server = LabServer(up)
    data_dir.mkdir(parents=True, exist_ok=True)
    server.tokens.update(add_people(up.env, PEOPLE))
    up.start()
    return server


@pytest.fixture(scope="module")
def lab_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LabServer]:
    """One lab server for a test module (start-up costs seconds), with the default settings: no trusted proxy."""
    server = start_lab_server(tmp_path_factory.mktemp("lab") / "var")
    yield server
    assert server.up.stop() == 0
