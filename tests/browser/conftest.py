"""Browser tests: Debian's Chromium driven by Playwright against a real `fringelab up` (Redis + worker + web).

Screenshots of each view go to test-artifacts/screenshots/ for a person to look at.
"""

from __future__ import annotations

import re
import shutil
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.support import UpProcess

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
SCREENSHOTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "screenshots"
DEMO_FRAMES = 6
DEMO_TIMEOUT_S = 900  # both cameras on a loaded 2-core machine: about 3 minutes alone, much more when shared
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


@pytest.fixture(scope="session")
def live_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[UpProcess]:
    up = UpProcess(tmp_path_factory.mktemp("live") / "var")
    up.start()
    yield up
    up.stop()


@pytest.fixture(scope="session")
def browser() -> Iterator[object]:
    if not Path(CHROMIUM).exists():
        pytest.skip(f"no Chromium at {CHROMIUM}: install it with `apt install chromium` to run the browser tests")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        launched = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield launched
        launched.close()


@pytest.fixture(scope="session")
def demo(live_server):  # type: ignore[no-untyped-def]
    """A demo experiment with both virtual cameras measured by the real worker, made once per session and shared
    by the tests that read results: {experiment_id, base (API URL), jobs: {(kind, camera name): job}}."""
    base = f"{live_server.base_url}/api/v1"
    made = httpx.post(f"{base}/demo", json={"cameras": ["kodak", "phantom"], "test_frames": DEMO_FRAMES}, timeout=30)
    assert made.status_code == 202, made.text
    experiment_id = made.json()["experiment_id"]
    deadline = time.monotonic() + DEMO_TIMEOUT_S
    while True:
        jobs = httpx.get(f"{base}/jobs", params={"experiment_id": experiment_id, "limit": 100}, timeout=30).json()
        failed = [job for job in jobs["items"] if job["state"] in ("failed", "cancelled")]
        assert not failed, f"demo jobs failed: {[(job['kind'], job['error']) for job in failed]}"
        topographies = [job for job in jobs["items"] if job["kind"] == "topography" and job["state"] == "succeeded"]
        if len(topographies) == 2:
            break
        assert time.monotonic() < deadline, f"the demo did not finish in {DEMO_TIMEOUT_S} s: {jobs['items']}"
        time.sleep(2)
    cameras = {c["id"]: c["name"] for c in httpx.get(f"{base}/experiments/{experiment_id}/cameras", timeout=30).json()}
    found = {}
    for job in jobs["items"]:
        if job["state"] != "succeeded" or job["kind"] == "ingest":
            continue
        recording = httpx.get(f"{base}/recordings/{job['spec']['recording_id']}", timeout=30).json()
        found[(job["kind"], cameras[recording["camera_id"]])] = job
    return {"experiment_id": experiment_id, "jobs": found, "base": base}


@pytest.fixture
def expected_console_errors() -> list[str]:
    """Regular expressions of the errors a test provokes on purpose. Each failed HTTP answer is listed as
    "STATUS METHOD URL" (e.g. "404 GET http://.../api/v1/jobs/x"; Chromium's console only says "Failed to load
    resource"), each other console error by its text; anything not matched fails the test."""
    return []


@pytest.fixture
def page(browser, live_server: UpProcess, expected_console_errors: list[str]) -> Iterator[object]:
    context = browser.new_context(  # type: ignore[attr-defined]
        viewport={"width": 1280, "height": 800}, base_url=live_server.base_url, accept_downloads=True
    )
    opened = context.new_page()
    errors: list[str] = []
    opened.on(
        "console",
        lambda message: (
            errors.append(message.text)
            if message.type == "error" and not message.text.startswith("Failed to load resource")
            else None
        ),
    )
    opened.on("pageerror", lambda error: errors.append(str(error)))
    opened.on(
        "response",
        lambda response: (
            errors.append(f"{response.status} {response.request.method} {response.url}")
            if response.status >= 400
            else None
        ),
    )
    yield opened
    context.close()
    unexpected = [e for e in errors if not any(re.search(p, e) for p in expected_console_errors)]
    assert unexpected == [], f"errors in the browser: {unexpected}"


def screenshot(page, name: str, *, full_page: bool = True) -> Path:  # type: ignore[no-untyped-def]
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    path = SCREENSHOTS / f"{name}.png"
    page.screenshot(path=str(path), full_page=full_page)
    return path
