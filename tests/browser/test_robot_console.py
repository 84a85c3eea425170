"""The admin robot console in Chromium, against the real agent and simulated robot."""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from core.audit.models import AuditEvent
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import MobileResourceFactory, UserFactory

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]


def test_an_admin_stops_and_releases_the_robot_from_the_console(browser, stack):
    MobileResourceFactory(agent_url=stack["agent_url"])
    UserFactory(username="root-admin", is_staff=True, is_superuser=True)
    context = browser.new_context(viewport={"width": 1280, "height": 1100})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    login(page, stack["web"], "root-admin", "correct horse battery")
    # The robots' consoles are in the top bar's "Testbed" menu, as are the other staff pages.
    page.get_by_test_id("menu-testbed").locator("summary").click()
    page.get_by_role("link", name="Robot console (mobile-1)").click()
    expect(page.locator("#st-link")).to_contain_text("up", timeout=15_000)
    expect(page.locator("#st-battery")).to_contain_text("V")

    page.get_by_label("Reason").first.fill("checking the console")
    page.get_by_role("button", name="Send").click()
    expect(page.locator("#console-feedback")).to_contain_text("Driving 0.3 m/s cw for 1 s")

    page.get_by_test_id("estop").click()
    expect(page.locator("#console-feedback")).to_contain_text("Emergency stop latched")
    expect(page.locator("#st-estop")).to_contain_text("LATCHED", timeout=5_000)
    # Latched: a banner at the top of the page, and the stop button says so.
    expect(page.locator("#estop-latched")).to_be_visible()
    expect(page.get_by_test_id("estop")).to_have_text("STOPPED (latched)")
    page.screenshot(path=str(SCREENSHOTS / "robot-console.png"), full_page=True)

    page.locator("#release-form").get_by_role("button").click()  # no reason: refused
    expect(page.locator("#console-feedback")).to_contain_text("Not released")
    # Said once: the refusal's detail names the field, its field's message is not repeated.
    said = page.locator("#console-feedback").inner_text()
    assert said.count("Say why it is safe to release the stop.") == 1, said
    page.locator("#release-form input[name=reason]").fill("rail inspected")
    page.locator("#release-form").get_by_role("button").click()
    # The portal's answer (after its audit row), not the status: the base station's status can
    # say released before the portal has written down who released it.
    # Released and reopened in one step (the box is ticked): bookings are open, whether or not
    # the health check had held the robot meanwhile.
    expect(page.locator("#console-feedback")).to_have_text(
        "Emergency stop released; bookings are open."
    )
    expect(page.locator("#st-estop")).to_have_text("released", timeout=5_000)
    expect(page.locator("#estop-latched")).to_be_hidden()
    expect(page.get_by_test_id("estop")).to_have_text("EMERGENCY STOP")
    # The health check may also have held the robot while its stop was latched (audited as
    # resource.hold); the console's own commands are these, in order.
    actions = list(
        AuditEvent.objects.filter(action__startswith="robot.")
        .order_by("pk")
        .values_list("action", flat=True)
    )
    assert actions == ["robot.control", "robot.stop", "robot.release"]
    assert not errors, errors
    context.close()
