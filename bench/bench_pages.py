"""First-content benchmark of the dashboard's pages: Chromium's first-contentful-paint of every page, against a
real `fringelab up`.

Run from the repository root:  .venv/bin/python bench/bench_pages.py [--repeats 5] [--no-demo]

It starts its own system (`python -m backend.cli up`: its own Redis, worker and web server, in a temporary data
directory, on a free loopback port) and stops it at the end. Unless `--no-demo`, a demo experiment (the virtual
kodak camera, 6 frames) is measured first, so that the pages of a recording, a job, a calibration report and a
topography viewer have something to show (a few minutes on a busy machine). Then Debian's Chromium (headless,
driven by Playwright) opens every page `--repeats` times, each time in a new tab: the first in a fresh browser
context (cold: nothing cached), the others in one context that has seen the page (warm: the cache as a person
returning to the dashboard has it).

Printed per page, as medians over the repeats: first content (Chromium's `first-contentful-paint`, ms from the
navigation's start), the page's own heading in place (its `h1`, ms), and, on pages that draw plots, when plotly.js
had loaded (ms; it is asked for only by the first figure drawn, after the page's content), and on pages with a job
form (an experiment's) when its inputs, built from the server's job spec schemas, are in place (ms; cold: the
first run, on a server process that has not been asked for the schemas yet; warm: the median of the others).
Goal (issue 27): first content within 300 ms on every page. Exit status 1 when a page misses it warm. With the
demo, the viewer's frame switch is timed too (fetch, decode and Plotly.react of the field and the profile,
`window.fringelab.frameSwitchMs`, over `--switches` moves of the slider; goal: median within 300 ms). The load
average of the machine is printed with the figures: on a shared machine they move with it.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.support import UpProcess  # noqa: E402

GOAL_MS = 300.0
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking"]
DEMO_TIMEOUT_S = 900.0
# Records when the page's own heading (the h1 each view puts first in <main>) appears, and on pages with a job
# form when its inputs built from the job spec schemas are in place, in ms since navigation.
HEADING_OBSERVER = """
new MutationObserver((_, observer) => {
  if (window.__headingMs === undefined && document.querySelector("main h1")) window.__headingMs = performance.now();
  if (document.querySelector('main form[aria-label="Start a job"] .spec-inputs select')) {
    window.__formMs = performance.now();
    observer.disconnect();
  }
}).observe(document, { childList: true, subtree: true });
"""
MEASURE = """() => {
  const paint = performance.getEntriesByName("first-contentful-paint")[0];
  const plotly = performance.getEntriesByType("resource").find((e) => e.name.includes("/vendor/plotly-"));
  return { fcp: paint ? paint.startTime : null, heading: window.__headingMs ?? null,
           plotly: plotly ? plotly.responseEnd : null, form: window.__formMs ?? null };
}"""


def demo_pages(base: str) -> dict[str, str]:
    """A measured kodak demo: its recording, topography job, calibration report and viewer."""
    made = httpx.post(f"{base}/demo", json={"cameras": ["kodak"], "test_frames": 6}, timeout=30)
    made.raise_for_status()
    experiment_id = made.json()["experiment_id"]
    deadline = time.monotonic() + DEMO_TIMEOUT_S
    while True:
        jobs = httpx.get(f"{base}/jobs", params={"experiment_id": experiment_id, "limit": 100}, timeout=30).json()
        failed = [job for job in jobs["items"] if job["state"] in ("failed", "cancelled")]
        if failed:
            raise SystemExit(f"the demo failed: {[(job['kind'], job['error']) for job in failed]}")
        done = {job["kind"]: job for job in jobs["items"] if job["state"] == "succeeded"}
        if "topography" in done:
            break
        if time.monotonic() > deadline:
            raise SystemExit(f"the demo did not finish in {DEMO_TIMEOUT_S:.0f} s")
        time.sleep(2)
    topography = done["topography"]
    calibration = next(job for kind, job in done.items() if "calibration" in kind)
    return {
        "experiment (demo)": f"/#/experiments/{experiment_id}",
        "recording": f"/#/recordings/{topography['spec']['recording_id']}",
        "job": f"/#/jobs/{topography['id']}",
        "calibration report": f"/#/jobs/{calibration['id']}/report",
        "viewer": f"/#/jobs/{topography['id']}/viewer",
    }


def measure(browser, base_url: str, path: str, repeats: int) -> dict[str, list[float]]:  # type: ignore[no-untyped-def]
    from playwright.sync_api import expect

    figures: dict[str, list[float]] = {"cold": [], "warm": [], "heading": [], "plotly": [], "form": [], "form cold": []}

    def new_context():  # type: ignore[no-untyped-def]
        made = browser.new_context(viewport={"width": 1280, "height": 800}, base_url=base_url)
        made.add_init_script(HEADING_OBSERVER)
        return made

    warm_context = new_context()
    for run in range(repeats):
        context = new_context() if run == 0 else warm_context
        tab = context.new_page()
        tab.goto(path)
        expect(tab.locator("main h1")).to_be_visible(timeout=30_000)
        tab.wait_for_load_state("networkidle")
        found = tab.evaluate(MEASURE)
        figures["cold" if run == 0 else "warm"].append(found["fcp"])
        if found["form"] is not None:
            figures["form cold" if run == 0 else "form"].append(found["form"])
        if run > 0:
            figures["heading"].append(found["heading"])
            if found["plotly"] is not None:
                figures["plotly"].append(found["plotly"])
        tab.close()
        if run == 0:
            context.close()
            # the warm context sees the page once before its timed runs
            seen = warm_context.new_page()
            seen.goto(path)
            expect(seen.locator("main h1")).to_be_visible(timeout=30_000)
            seen.wait_for_load_state("networkidle")
            seen.close()
    warm_context.close()
    return figures


def frame_switches(browser, base_url: str, path: str, switches: int) -> list[float]:  # type: ignore[no-untyped-def]
    """Times (ms) of `switches` frame moves in the viewer at `path`, back and forth over its frames."""
    from playwright.sync_api import expect

    context = browser.new_context(viewport={"width": 1280, "height": 800}, base_url=base_url)
    tab = context.new_page()
    tab.goto(path)
    slider = tab.get_by_role("slider", name="Frame")
    expect(slider).to_be_visible(timeout=30_000)
    tab.wait_for_function("() => window.fringelab.frameSwitchMs.length >= 1")
    last = int(slider.get_attribute("max") or 1)
    slider.focus()
    slider.press("End")
    tab.wait_for_function(f"() => Number(document.querySelector('input.scrubber').value) === {last}")
    tab.wait_for_load_state("networkidle")
    tab.evaluate("() => { window.fringelab.frameSwitchMs = []; }")
    for i in range(switches):
        slider.press("ArrowLeft" if (i // max(1, last)) % 2 == 0 else "ArrowRight")
        tab.wait_for_function(f"() => window.fringelab.frameSwitchMs.length >= {i + 1}")
    times = list(tab.evaluate("() => window.fringelab.frameSwitchMs"))
    context.close()
    return times


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="times each page is opened (the first cold)")
    parser.add_argument("--no-demo", action="store_true", help="skip the demo: only the pages that need no results")
    parser.add_argument("--switches", type=int, default=20, help="frame switches timed in the demo's viewer")
    args = parser.parse_args()
    if args.repeats < 2:
        parser.error("--repeats must be at least 2 (one cold, one warm)")
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory(prefix="bench-pages-") as tmp:
        up = UpProcess(Path(tmp) / "var")
        up.start()
        try:
            base = f"{up.base_url}/api/v1"
            experiment = httpx.post(f"{base}/experiments", json={"name": "bench"}, timeout=30).json()
            pages = {
                "experiments": "/#/experiments",
                "experiment (empty)": f"/#/experiments/{experiment['id']}",
                "jobs": "/#/jobs",
                "queue": "/#/queue",
                "API tokens": "/#/tokens",
                "system": "/#/system",
                "help": "/#/help",
                "help: method": "/#/help/method",
            }
            if not args.no_demo:
                pages.update(demo_pages(base))
            with sync_playwright() as playwright:
                browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                results = {name: measure(browser, up.base_url, path, args.repeats) for name, path in pages.items()}
                switch_ms = [] if args.no_demo else frame_switches(browser, up.base_url, pages["viewer"], args.switches)
                browser.close()
        finally:
            up.stop()

    def median(values: list[float]) -> str:
        found = [v for v in values if v is not None]
        return f"{statistics.median(found):8.0f}" if found else "       -"

    print(f"first content, ms (medians; cold: 1 run, warm: {args.repeats - 1} runs); goal {GOAL_MS:.0f} ms")
    print(f"{'page':22s} {'cold FCP':>8s} {'warm FCP':>8s} {'heading':>8s} {'plotly':>8s} {'form':>8s} {'form':>8s}")
    print(f"{'':22s} {'':8s} {'':8s} {'':8s} {'':8s} {'cold':>8s} {'warm':>8s}")
    missed = []
    for name, f in results.items():
        print(f"{name:22s} {median(f['cold'])} {median(f['warm'])} {median(f['heading'])} {median(f['plotly'])} "
              f"{median(f['form cold'])} {median(f['form'])}")  # fmt: skip
        warm = [v for v in f["warm"] if v is not None]
        if not warm or statistics.median(warm) > GOAL_MS:
            missed.append(name)
    if switch_ms:
        print(
            f"viewer frame switch ({len(switch_ms)} moves): median {statistics.median(switch_ms):.0f} ms, "
            f"max {max(switch_ms):.0f} ms; goal: median {GOAL_MS:.0f} ms"
        )
        if statistics.median(switch_ms) > GOAL_MS:
            missed.append("viewer frame switch")
    load = " ".join(f"{v:.2f}" for v in os.getloadavg())
    print(f"load average {load} on {os.cpu_count()} cores")
    if missed:
        print(f"goal missed on: {', '.join(missed)}")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
