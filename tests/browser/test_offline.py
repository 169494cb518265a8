"""Every page works with no internet: Chromium is allowed to reach the fringelab server only (every other request is
aborted and counted), loads each page of the dashboard on a measured demo experiment and the API docs (Swagger
UI and ReDoc), and finds no failed request, no request to anywhere else and no console error."""

from __future__ import annotations

from urllib.parse import urlsplit

import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.slow]


def test_every_page_loads_with_only_the_server_reachable(page, live_server, demo):
    server = urlsplit(live_server.base_url).netloc
    elsewhere: list[str] = []
    failed: list[str] = []

    def only_the_server(route):  # type: ignore[no-untyped-def]
        if urlsplit(route.request.url).netloc == server or route.request.url.startswith(("data:", "blob:")):
            route.continue_()
        else:
            elsewhere.append(route.request.url)
            route.abort("internetdisconnected")

    page.context.route("**/*", only_the_server)

    # A request the page drops because we navigate on (net::ERR_ABORTED) is not a failure of the network.
    def note_failure(request):  # type: ignore[no-untyped-def]
        if request.failure != "net::ERR_ABORTED":
            failed.append(f"{request.failure} {request.url}")

    page.on("requestfailed", note_failure)

    jobs = demo["jobs"]
    topography = jobs[("topography", "kodak")]
    pages = {
        "/#/experiments": ("heading", "Experiments"),
        f"/#/experiments/{demo['experiment_id']}": ("region", "Camera kodak"),
        f"/#/recordings/{topography['spec']['recording_id']}": ("heading", "QA warnings"),
        "/#/jobs": ("table", "All jobs"),
        f"/#/jobs/{topography['id']}": ("log", "Job log"),
        f"/#/jobs/{jobs[('camera_calibration', 'kodak')]['id']}/report": ("region", "Verdict"),
        f"/#/jobs/{jobs[('projector_calibration', 'kodak')]['id']}/report": ("img", "Sensitivity map"),
        f"/#/jobs/{topography['id']}/viewer": ("img", "Deflection map"),
        "/#/queue": ("heading", "Queue"),
        "/#/help": ("list", "Documents"),
        "/#/help/method?section=4-projector-calibration-look-up-table": ("heading", "The measurement method"),
        "/#/tokens": ("heading", "API tokens"),
        "/#/system": ("heading", "System"),
    }
    for path, (role, name) in pages.items():
        page.goto(path)
        expect(page.get_by_role(role, name=name).first).to_be_visible(timeout=30_000)
        page.wait_for_load_state("networkidle")
    page.goto("/api/docs")
    expect(page.locator(".swagger-ui .info .title")).to_contain_text("fringelab", timeout=30_000)
    expect(page.locator(".opblock").first).to_be_visible()
    screenshot(page, "offline-swagger-ui", full_page=False)
    page.goto("/api/redoc")
    expect(page.locator("redoc h1, [role='main'] h1").first).to_contain_text("fringelab", timeout=30_000)
    page.wait_for_load_state("networkidle")
    screenshot(page, "offline-redoc", full_page=False)
    fonts = page.evaluate("() => [...document.fonts].map((font) => font.family)")
    assert not fonts, f"web fonts were declared on the docs page: {fonts}"
    assert elsewhere == [], f"requests to anything but the server: {elsewhere}"
    assert failed == [], f"failed requests: {failed}"
