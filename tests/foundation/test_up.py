"""`fringelab up` as a user runs it: a subprocess on free ports, healthy with a live worker, a task end to end,
and after SIGTERM no child left alive (checked by PID)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys

import httpx
import psutil
import pytest

from backend.services import free_port
from backend.settings import Settings
from tests.support import wait_for
from worker.celery_app import create_celery

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def _healthy(url: str) -> bool:
    try:
        response = httpx.get(url, timeout=5)
    except httpx.HTTPError:
        return False
    return response.status_code == 200 and response.json()["workers"] >= 1


def test_up_runs_everything_and_sigterm_leaves_no_child(tmp_path):
    port = free_port()
    clean = {k: v for k, v in os.environ.items() if not k.startswith("FRINGELAB_")}
    env = {**clean, "FRINGELAB_PORT": str(port), "FRINGELAB_DATA_DIR": str(tmp_path / "var")}
    log = (tmp_path / "up.log").open("w+")
    up = subprocess.Popen([sys.executable, "-m", "backend.cli", "up"], env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        wait_for(lambda: _healthy(f"http://127.0.0.1:{port}/api/v1/health"), timeout_s=120, what="a healthy system")
        children = psutil.Process(up.pid).children(recursive=True)
        names = " ".join(" ".join(c.cmdline()) for c in children)
        assert "redis-server" in names and " worker" in names and " api" in names
        assert sum("worker" in " ".join(c.cmdline()) for c in children) >= 2  # the worker and its pool processes

        banner = f"fringelab is running at http://127.0.0.1:{port}"

        def banner_printed() -> str:
            text = (tmp_path / "up.log").read_text()
            return text if banner in text else ""

        printed = wait_for(banner_printed, timeout_s=30, what=banner)
        redis_url = re.search(r"Redis (redis://\S+)\)", str(printed)).group(1)  # type: ignore[union-attr]
        assert redis_url != "redis://127.0.0.1:6379/0"  # its own Redis, not the user's

        app = create_celery(Settings(_env_file=None, redis_url=redis_url))  # type: ignore[call-arg]
        assert app.send_task("fringelab.ping", args=["end-to-end"]).get(timeout=30)["payload"] == "end-to-end"

        second = subprocess.run(
            [sys.executable, "-m", "backend.cli", "up"], env=env, capture_output=True, text=True, timeout=60
        )
        assert second.returncode != 0
        assert "already running" in second.stderr

        up.send_signal(signal.SIGTERM)
        assert up.wait(timeout=60) == 0
        alive = [c.pid for c in children if c.is_running() and c.status() != psutil.STATUS_ZOMBIE]
        assert alive == [], f"children left behind: {alive}"
        assert "fringelab stopped." in (tmp_path / "up.log").read_text()
    finally:
        if up.poll() is None:
            up.kill()
        log.close()
