"""Two-factor authentication for staff and self-service API tokens, in Chromium."""

from __future__ import annotations

import io
import re

import pytest
from allauth.mfa.models import Authenticator
from django.core.management import call_command
from playwright.sync_api import Page, expect
from typer.testing import CliRunner

from amazing_cli.main import app
from core.accounts.mfa import STAFF_ENROLMENT_REFUSED
from core.accounts.models import ApiToken, User
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import MobileResourceFactory, UserFactory, next_totp_code, totp_code

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]

SETUP_URL = re.compile(r"2fa(/|%2F)totp(/|%2F)activate")


def _csp_watch(page: Page) -> list[str]:
    refused: list[str] = []
    page.on(
        "console",
        lambda m: "Content Security Policy" in m.text and refused.append(f"{page.url}: {m.text}"),
    )
    return refused


def test_staff_without_mfa_set_it_up_before_the_robot_approvals_or_admin(browser, live_server):
    web = live_server.url
    MobileResourceFactory(name="mobile-1")
    UserFactory(username="sam", is_staff=True, is_superuser=True, mfa=False)
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    page = context.new_page()
    refused = _csp_watch(page)
    login(page, web, "sam", "correct horse battery")
    for path in ("/robot/mobile-1/", "/approvals/", "/admin/"):
        page.goto(f"{web}{path}")
        # To the set-up page, through allauth's password confirmation first.
        expect(page).to_have_url(SETUP_URL)
        expect(page.get_by_text("Staff accounts need two-factor authentication")).to_be_visible()
    page.get_by_label("Password").fill("correct horse battery")
    page.get_by_role("button", name="Confirm").click()
    expect(page.get_by_role("heading", name="Activate Authenticator App")).to_be_visible()
    # What a person does with an authenticator app: take the secret, type the code it shows.
    # Its password alone does not let a staff account choose its second factor: refused...
    secret = page.locator("#authenticator_secret").input_value()
    page.get_by_label("Authenticator code").fill(totp_code(secret))
    page.get_by_role("button", name="Activate").click()
    expect(page.get_by_text(STAFF_ENROLMENT_REFUSED)).to_be_visible()
    assert not Authenticator.objects.filter(user__username="sam").exists()
    # ...until another admin allows it; then the same page takes the code.
    call_command("mfa_enrolment_allow", "sam", stdout=io.StringIO())
    secret = page.locator("#authenticator_secret").input_value()
    page.get_by_label("Authenticator code").fill(totp_code(secret))
    page.get_by_role("button", name="Activate").click()
    expect(page.get_by_role("heading", name="Recovery Codes")).to_be_visible()
    assert not User.objects.get(username="sam").mfa_enrolment_allowed  # used up
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SCREENSHOTS / "mfa-recovery-codes.png"), full_page=True)
    # This session signed in with the password alone: a staff page asks for the code first.
    page.goto(f"{web}/robot/mobile-1/")
    expect(page).to_have_url(re.compile(r"/accounts/2fa/reauthenticate/"))
    given = totp_code(secret)
    page.locator("input[name=code]").fill(given)
    page.get_by_role("button", name="Confirm").click()
    expect(page).to_have_url(f"{web}/robot/mobile-1/")
    for path, heading in (
        ("/robot/mobile-1/", "mobile-1"),
        ("/approvals/", "Bookings awaiting approval"),
        ("/admin/", "Site administration"),
    ):
        page.goto(f"{web}{path}")
        expect(page).to_have_url(f"{web}{path}")
        expect(page.get_by_role("heading", name=re.compile(heading)).first).to_be_visible()
    assert not refused, refused
    context.close()

    # The next sign-in asks for the code: a wrong one is refused, the app's is taken.
    context = browser.new_context(viewport={"width": 375, "height": 800})
    page = context.new_page()
    page.goto(f"{web}/approvals/")
    page.get_by_label("Username or email").fill("sam")
    page.get_by_label("Password").fill("correct horse battery")
    page.get_by_role("button", name="Log in").click()
    expect(page).to_have_url(re.compile(r"/accounts/2fa/authenticate/"))
    page.locator("input[name=code]").fill("000000")
    page.get_by_role("button", name="Sign In").click()
    expect(page.get_by_text("Incorrect code")).to_be_visible()
    page.locator("input[name=code]").fill(next_totp_code(secret, given))
    page.get_by_role("button", name="Sign In").click()
    expect(page).to_have_url(f"{web}/approvals/")
    context.close()


def test_a_user_makes_a_token_uses_it_with_amazing_revokes_it_and_is_refused(
    browser, live_server, monkeypatch, tmp_path
):
    web = live_server.url
    UserFactory(username="tess")
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.delenv("AMAZING_TOKEN", raising=False)
    monkeypatch.delenv("AMAZING_URL", raising=False)
    context = browser.new_context(
        viewport={"width": 375, "height": 900}, permissions=["clipboard-read", "clipboard-write"]
    )
    page = context.new_page()
    refused = _csp_watch(page)
    login(page, web, "tess", "correct horse battery")
    page.get_by_test_id("menu-account").locator("summary").click()
    page.get_by_role("link", name="Tokens").click()
    page.get_by_label("Name").fill("laptop")
    page.get_by_label("Expires in (days)").fill("30")
    with page.expect_response(lambda r: r.request.method == "POST") as made:
        page.get_by_test_id("create-token").click()
    # In the answer to the POST that made it, which no cache keeps.
    assert "no-store" in made.value.headers["cache-control"]
    token = page.get_by_test_id("new-token-value").input_value()
    assert token.startswith("amz_")
    page.get_by_role("button", name="Copy").click()
    expect(page.locator("#copy-token-status")).to_have_text("Copied.")
    assert page.evaluate("navigator.clipboard.readText()") == token
    example = f'curl -H "Authorization: Token {token}" {web}/api/v1/me/'
    expect(page.get_by_text(example)).to_be_visible()
    page.screenshot(path=str(SCREENSHOTS / "api-tokens.png"), full_page=True)

    cli = CliRunner()
    signed_in = cli.invoke(app, ["login", "--url", web, "--token", token])
    assert signed_in.exit_code == 0, signed_in.output
    assert "as tess" in signed_in.output
    quota = cli.invoke(app, ["quota"])
    assert quota.exit_code == 0, quota.output

    # Shown once: the page asked for again shows it no more, and asking made no second one.
    page.goto(f"{web}/account/tokens/")
    expect(page.get_by_test_id("new-token-value")).to_have_count(0)
    assert ApiToken.objects.count() == 1
    row = page.get_by_test_id("tokens").get_by_role("row", name=re.compile("laptop"))
    expect(row).not_to_contain_text("never used")
    expect(row.get_by_role("cell").nth(3)).not_to_have_text("never")
    row.get_by_role("button", name="Revoke").click()
    expect(page.get_by_text("Token revoked")).to_be_visible()
    assert not ApiToken.objects.exists()

    refused_quota = cli.invoke(app, ["quota"])
    assert refused_quota.exit_code == 3, refused_quota.output
    assert "Invalid token" in refused_quota.stderr
    assert not refused, refused
    context.close()
