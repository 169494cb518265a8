"""`fringelab up` as a user runs it: a subprocess on free ports, healthy with a live worker, a task end to end,
and after SIGTERM no child left alive (checked by PID)."""

from __future__ import annotations

import json
import re
import subprocess

import psutil
import pytest

from fringelab.core.queue import create_celery
from fringelab.core.settings import Settings
from tests.support import UpProcess

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def test_up_runs_everything_and_sigterm_leaves_no_child(tmp_path):
    up = UpProcess(tmp_path / "var")
    up.start()
    try:
        assert up.process is not None
        children = psutil.Process(up.process.pid).children(recursive=True)
        names = " ".join(" ".join(c.cmdline()) for c in children)
        assert "redis-server" in names and " worker" in names and " api" in names
        assert sum("worker" in " ".join(c.cmdline()) for c in children) >= 2  # the worker and its pool processes
        # The worker computes at FRINGELAB_WORKER_NICE (10), the web server at the priority `up` has (0). Niceness
        # only goes up: under a runner already nicer than 10 (`nice -n 15 pytest`) the worker keeps the runner's.
        worker_nice = max(10, psutil.Process().nice())
        assert {c.nice() for c in children if "worker" in " ".join(c.cmdline())} == {worker_nice}
        assert {c.nice() for c in children if " api" in " ".join(c.cmdline())} == {psutil.Process().nice()}

        logged_url = re.search(r"Redis (redis://\S+)\)", up.log()).group(1)  # type: ignore[union-attr]
        assert logged_url != "redis://127.0.0.1:6379/0"  # its own Redis, not the user's
        # its password is in the supervisor's file (this user's only), never in the log
        redis_url = json.loads((tmp_path / "var" / "supervisor.json").read_text())["redis_url"]
        password = redis_url.split("@")[0].rsplit(":", 1)[-1]
        assert password and password not in up.log()
        app = create_celery(Settings(_env_file=None, redis_url=redis_url))  # type: ignore[call-arg]
        assert app.send_task("fringelab.ping", args=["end-to-end"]).get(timeout=30)["payload"] == "end-to-end"

        second = subprocess.run(up.argv, env=up.env, capture_output=True, text=True, timeout=60)
        assert second.returncode != 0
        assert "already running" in second.stderr

        assert up.stop() == 0
        alive = [c.pid for c in children if c.is_running() and c.status() != psutil.STATUS_ZOMBIE]
        assert alive == [], f"children left behind: {alive}"
        assert "fringelab stopped." in up.log()
    finally:
        if up.process and up.process.poll() is None:
            up.process.kill()
