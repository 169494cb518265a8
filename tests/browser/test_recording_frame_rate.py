"""The recording page shows the frame rate the frame times give, with the header's beside it where they differ."""

from __future__ import annotations

import httpx
import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot
from tests.formats.recording_files import stripe_frames, write_cine
from tests.support import wait_for

pytestmark = [pytest.mark.browser, pytest.mark.integration]


def test_frame_rate_from_the_time_stamps_with_the_header_beside(page, live_server, tmp_path):  # type: ignore[no-untyped-def]
    base = f"{live_server.base_url}/api/v1"
    experiment = httpx.post(f"{base}/experiments", json={"name": "frame rates"}, timeout=30).json()
    body = {"name": "phantom", "image_width_px": 64, "image_height_px": 48, "pixel_pitch_um": 20.0}
    camera = httpx.post(f"{base}/experiments/{experiment['id']}/cameras", json=body, timeout=30)
    assert camera.status_code == 201, camera.text
    cine = write_cine(tmp_path / "stamps.cine", stripe_frames(4), fps=90000, stamp_fps=9000)
    created = httpx.put(f"{base}/uploads/cameras/{camera.json()['id']}/stamps.cine", params={"kind": "test"},
                        content=cine.read_bytes(), timeout=60)  # fmt: skip
    assert created.status_code == 201, created.text
    recording_id = created.json()["id"]

    def ready() -> bool:
        return httpx.get(f"{base}/recordings/{recording_id}", timeout=30).json()["state"] == "ready"

    wait_for(ready, timeout_s=120, what="the .cine to be ingested", interval_s=0.5)
    page.goto(f"/#/recordings/{recording_id}")
    expect(page.locator("dl.facts")).to_contain_text("9000 frames/s (header: 90000 frames/s)", timeout=30_000)
    screenshot(page, "recording-frame-rate", full_page=False)
