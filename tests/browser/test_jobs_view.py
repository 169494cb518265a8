"""Jobs in real Chromium against a real worker, with the job system's own self-test (no upload needed): live
progress over Server-Sent Events up to 100 %, the job page with its log, cancel and retry."""

from __future__ import annotations

import re

import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration]


def run_selftest(page, *, frames: int, size_px: int) -> None:
    page.goto("/#/system")
    form = page.get_by_role("form", name="Self-test of the workers")
    form.get_by_label("Frames", exact=True).fill(str(frames))
    form.get_by_label("Frame size (px)").fill(str(size_px))
    form.get_by_role("button", name="Run the self-test").click()


def test_selftest_progress_reaches_100_percent_live_and_its_log_shows(page):
    streams: list[str] = []
    page.on("request", lambda request: streams.append(request.url) if request.url.endswith("/events") else None)
    run_selftest(page, frames=60, size_px=64)
    form = page.get_by_role("form", name="Self-test of the workers")
    bar = form.get_by_role("progressbar", name=re.compile(r"^Progress of Self-test"))
    expect(bar).to_have_js_property("value", 1, timeout=60_000)
    expect(form).to_contain_text("100 %")
    expect(form).to_contain_text("succeeded")
    assert streams, "the progress did not come over Server-Sent Events"
    form.get_by_role("link", name=re.compile(r"^Self-test")).click()
    expect(page.get_by_role("heading", name=re.compile(r"^Self-test [0-9a-f]{8}$"))).to_be_visible()
    log = page.get_by_role("log", name="Job log")
    expect(log).to_contain_text("succeeded")
    expect(page.get_by_role("table", name="Result files")).to_contain_text("selftest")
    screenshot(page, "job")


def test_cancel_then_retry_a_job(page, expected_console_errors):
    run_selftest(page, frames=100_000, size_px=1024)  # minutes of work: it is still running when cancelled
    form = page.get_by_role("form", name="Self-test of the workers")
    expect(form).to_contain_text("running", timeout=30_000)
    form.get_by_role("button", name=re.compile(r"^Cancel Self-test")).click()
    expect(form).to_contain_text(re.compile("cancelled|stopping"))
    form.get_by_role("link", name=re.compile(r"^Self-test")).click()
    expect(page.get_by_role("heading", name=re.compile(r"^Self-test [0-9a-f]{8}$"))).to_be_visible()
    retry = page.get_by_role("button", name=re.compile(r"^Retry Self-test"))
    expect(retry).to_be_visible(timeout=30_000)
    first = page.url
    retry.click()
    expect(page).not_to_have_url(first)
    expect(page.get_by_text(re.compile(r"2, retry of"))).to_be_visible()
    # The retry is as long as the first attempt: cancel it too, so that the worker is free for other tests.
    page.get_by_role("button", name=re.compile(r"^Cancel Self-test")).click()
    expect(page.get_by_role("log", name="Job log")).to_contain_text("cancel", timeout=30_000)
