"""With accounts on: the API's 401 opens the login form, a wrong password is said so, and the API tokens page
creates a token (its secret shown once), lists it and revokes it."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator

import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot
from tests.support import UpProcess

pytestmark = [pytest.mark.browser, pytest.mark.integration]
PASSWORD = "correct horse battery"


@pytest.fixture(scope="module")
def auth_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[UpProcess]:
    up = UpProcess(tmp_path_factory.mktemp("auth") / "var", extra_env={"FRINGELAB_AUTH_ENABLED": "true"})
    up.start()
    subprocess.run(
        [sys.executable, "-m", "backend.cli", "user", "add", "ada", "--password-stdin"],
        input=f"{PASSWORD}\n",
        text=True,
        env=up.env,
        check=True,
        capture_output=True,
    )
    yield up
    up.stop()


def test_login_then_create_list_and_revoke_a_token(browser, auth_server):
    context = browser.new_context(viewport={"width": 1280, "height": 800}, base_url=auth_server.base_url)
    page = context.new_page()
    console_errors: list[str] = []
    page.on("console", lambda message: console_errors.append(message.text) if message.type == "error" else None)
    try:
        page.goto("/#/tokens")
        expect(page.get_by_role("heading", name="Log in")).to_be_visible()
        page.get_by_label("Username").fill("ada")
        page.get_by_label("Password").fill("not the password")
        page.get_by_role("button", name="Log in").click()
        expect(page.get_by_role("alert")).to_contain_text("wrong username or password")
        page.get_by_label("Password").fill(PASSWORD)
        page.get_by_role("button", name="Log in").click()

        expect(page.get_by_role("heading", name="API tokens")).to_be_visible()
        expect(page.get_by_role("banner")).to_contain_text("ada (member)")
        page.get_by_label("Token name").fill("nightly upload script")
        page.get_by_role("button", name="Create token").click()
        secret = page.get_by_label("New token secret")
        expect(secret).to_be_visible()
        assert secret.input_value().startswith("flb_")
        tokens = page.get_by_role("table", name="Your API tokens")
        expect(tokens.get_by_role("row").filter(has_text="nightly upload script")).to_be_visible()
        screenshot(page, "api-tokens")
        page.once("dialog", lambda dialog: dialog.accept())
        tokens.get_by_role("button", name="Revoke token nightly upload script").click()
        expect(tokens.get_by_role("row").filter(has_text="nightly upload script")).to_contain_text("revoked")
    finally:
        context.close()
    # 401s are the answers that open the login form; anything else is a fault.
    assert [e for e in console_errors if "status of 401" not in e] == []


def test_a_jobs_list_open_when_the_account_is_disabled_says_that_access_ended(browser, auth_server):
    """The list's event stream ends with "forbidden" once the reader's access ends (re-checked every 2 s): the page
    says why live updates stopped, instead of a lost connection."""
    subprocess.run(
        [sys.executable, "-m", "backend.cli", "user", "add", "bob", "--password-stdin"],
        input=f"{PASSWORD}\n", text=True, env=auth_server.env, check=True, capture_output=True,
    )  # fmt: skip
    context = browser.new_context(viewport={"width": 1280, "height": 800}, base_url=auth_server.base_url)
    page = context.new_page()
    try:
        page.goto("/#/jobs")
        page.get_by_label("Username").fill("bob")
        page.get_by_label("Password").fill(PASSWORD)
        page.get_by_role("button", name="Log in").click()
        expect(page.get_by_text("No jobs yet.")).to_be_visible()  # read: the list's event stream opens then
        page.wait_for_timeout(500)
        subprocess.run([sys.executable, "-m", "backend.cli", "user", "disable", "bob"], env=auth_server.env,
                       check=True, capture_output=True)  # fmt: skip
        alert = page.get_by_role("alert")
        expect(alert).to_contain_text("access ended", timeout=15_000)
        expect(alert).to_contain_text("live updates stopped")
        screenshot(page, "jobs-list-access-ended")
    finally:
        context.close()
