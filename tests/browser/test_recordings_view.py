"""Experiments, cameras and uploads in real Chromium against a real server and worker: the page's own upload
control (tus) with progress, pause and resume, the server's refusal shown on the file's row, and the recording
page's frame scrubber and QA."""

from __future__ import annotations

import re
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration]


def stripe_zip(path: Path, *, n_frames: int, height: int = 120, width: int = 160, noise: float = 3.0) -> Path:
    """A test recording: a ZIP of PNG stripe frames (shifting 1 px per frame) with its frames.csv."""
    rng = np.random.default_rng(7)
    columns = np.arange(width)
    with zipfile.ZipFile(path, "w") as archive:
        for i in range(n_frames):
            row = np.where(((columns + i) // 6) % 2, 200.0, 40.0)
            frame = np.clip(row[None, :] + rng.normal(0, noise, (height, width)), 0, 255).astype(np.uint8)
            ok, png = cv2.imencode(".png", frame)
            assert ok
            archive.writestr(f"frame_{i:04d}.png", png.tobytes())
        lines = "".join(f"{i},{i * 1e-4:.6f},{0.5 * i},{1.5 * i}\n" for i in range(n_frames))
        archive.writestr("frames.csv", "frame,time_s,punch_displacement_mm,force_kN\n" + lines)
    return path


def new_experiment_with_camera(page, name: str) -> None:
    page.goto("/#/experiments")
    form = page.get_by_role("form", name="New experiment")
    form.get_by_label("Name").fill(name)
    form.get_by_label("Plate").fill("AA6016-T4, 1.5 mm")
    form.get_by_role("button", name="Create experiment").click()
    expect(page.get_by_role("heading", name=name)).to_be_visible()
    cameras = page.get_by_role("form", name="Add a camera")
    cameras.get_by_label("Camera name").fill("left")
    cameras.get_by_label("Image width (px)").fill("160")
    cameras.get_by_label("Image height (px)").fill("120")
    cameras.get_by_label("Pixel pitch u (µm)").fill("20")
    cameras.get_by_role("button", name="Add camera").click()
    expect(page.get_by_role("region", name="Camera left")).to_be_visible()


def test_upload_through_the_page_then_scrub_the_recording(page, tmp_path, expected_console_errors):
    expected_console_errors.append(r"^415 (POST|PATCH) .*/api/v1/uploads")  # the file the server refuses, on purpose
    recording = stripe_zip(tmp_path / "punch_test.zip", n_frames=12)
    refused = tmp_path / "notes.zip"
    refused.write_bytes(b"these are notes, not frames")
    new_experiment_with_camera(page, "Upload through the page")
    camera = page.get_by_role("region", name="Camera left")
    camera.get_by_label("Kind of the recordings to upload to left").select_option(label="Test")
    camera.get_by_label("Choose files").set_input_files([recording, refused])

    expect(camera.get_by_role("progressbar", name="Upload progress of punch_test.zip")).to_have_js_property(
        "value", 100, timeout=30_000
    )
    row = camera.get_by_role("listitem").filter(has_text="notes.zip")
    expect(row).to_contain_text("not a recording format", timeout=30_000)
    expect(page.get_by_role("alert")).to_contain_text("notes.zip")
    expect(row.get_by_role("button", name="Resume upload of notes.zip")).to_be_hidden()  # refused: no retry
    table = camera.get_by_role("table", name="Recordings of left")
    expect(table.get_by_role("row").filter(has_text="punch_test.zip")).to_contain_text("ready", timeout=60_000)
    screenshot(page, "experiment")

    table.get_by_role("link", name="punch_test.zip").click()
    expect(page.get_by_role("heading", name="punch_test.zip")).to_be_visible()
    slider = page.get_by_role("slider", name="Frame")
    slider.focus()
    for _ in range(3):
        slider.press("ArrowRight")
    expect(page.get_by_text("Frame 3 (4 of 12)")).to_be_visible()  # 12 frames, numbered from 0
    image = page.get_by_role("img", name="Frame 3 of the recording")
    page.wait_for_function(
        "() => { const i = document.querySelector('img.frame'); return i.complete && i.naturalWidth === 160; }"
    )
    expect(image).to_be_visible()
    expect(page.get_by_role("img", name="Per-frame QA")).to_be_visible()
    screenshot(page, "recording")


def test_a_folder_of_frames_is_packed_in_the_browser_and_becomes_a_recording(page, tmp_path):
    """The folder chooser (as a drop of a folder): the page packs the frames into a ZIP (zip.js, CRC-32 and all)
    that the server's own reader accepts, frames in natural order and the sidecar inside."""
    packed = stripe_zip(tmp_path / "packed.zip", n_frames=6)
    folder = tmp_path / "run_7"
    folder.mkdir()
    with zipfile.ZipFile(packed) as archive:
        archive.extractall(folder)
    new_experiment_with_camera(page, "Folder upload")
    camera = page.get_by_role("region", name="Camera left")
    camera.get_by_label("Kind of the recordings to upload to left").select_option(label="Test")
    camera.get_by_label("Choose a folder").set_input_files(folder)
    expect(camera.get_by_role("progressbar", name="Upload progress of run_7.zip")).to_have_js_property(
        "value", 100, timeout=30_000
    )
    row = camera.get_by_role("table", name="Recordings of left").get_by_role("row").filter(has_text="run_7.zip")
    expect(row).to_contain_text("ready", timeout=60_000)
    expect(row).to_contain_text("6 × 160×120 px")


def test_pause_and_resume_an_upload(page, tmp_path, expected_console_errors):
    """With the upload throttled to 2 MB/s, pause part-way, see the bar hold, resume, and finish."""
    # The first PATCH after a resume may meet the server still writing the aborted one's last bytes: it answers
    # 409 (offset mismatch), tus-js-client asks for the offset again and carries on.
    expected_console_errors.append(r"^409 PATCH .*/api/v1/uploads/")
    recording = stripe_zip(tmp_path / "slow.zip", n_frames=40, height=480, width=640, noise=60.0)
    assert recording.stat().st_size > 4_000_000  # noisy frames do not compress: a few seconds at 2 MB/s
    new_experiment_with_camera(page, "Pause and resume")
    cdp = page.context.new_cdp_session(page)
    cdp.send("Network.enable")
    cdp.send(
        "Network.emulateNetworkConditions",
        {"offline": False, "latency": 0, "downloadThroughput": -1, "uploadThroughput": 2_000_000},
    )
    camera = page.get_by_role("region", name="Camera left")
    camera.get_by_label("Kind of the recordings to upload to left").select_option(label="Test")
    camera.get_by_label("Choose files").set_input_files([recording])
    bar = "document.querySelector('progress[aria-label=\"Upload progress of slow.zip\"]')"
    page.wait_for_function(f"() => {bar} && {bar}.value >= 10")
    row = camera.get_by_role("listitem").filter(has_text="slow.zip")
    expect(row).to_contain_text(re.compile(r"\d+ % · [\d.]+ [kM]B/s · .* left"))  # speed and time left
    camera.get_by_role("button", name="Pause upload of slow.zip").click()
    expect(row).to_contain_text("paused at")
    paused_at = page.evaluate(f"() => {bar}.value")
    assert 10 <= paused_at < 100
    cdp.send(
        "Network.emulateNetworkConditions",
        {"offline": False, "latency": 0, "downloadThroughput": -1, "uploadThroughput": -1},
    )
    row.get_by_role("button", name="Resume upload of slow.zip").click()
    expect(camera.get_by_role("progressbar", name="Upload progress of slow.zip")).to_have_js_property(
        "value", 100, timeout=30_000
    )
    expect(row).to_contain_text("done · recording")
