"""The pages update live in Chromium, and survive the web process restarting under them.

Real processes (``fault_stack``: web, workers, beat, two agents, a Redis of its own). The run
page, the robot console and the calendar follow their Server-Sent Events streams; when the
web process goes away a page says "reconnecting", polls, and picks the stream up again.
"""

from __future__ import annotations

import signal
from datetime import datetime, time, timedelta
from time import monotonic
from zoneinfo import ZoneInfo

import pytest
from django.conf import settings
from django.utils import timezone
from playwright.sync_api import Page, expect

from tests.browser.conftest import login
from tests.factories import FixedResourceFactory, MobileResourceFactory, UserFactory
from tests.integration.experimenter import Experimenter
from tests.integration.stack import Stack

pytestmark = [pytest.mark.browser, pytest.mark.long, pytest.mark.django_db(transaction=True)]

PASSWORD = "correct horse battery"


SCRIPT_ERRORS: list[str] = []


def _page(browser, stack: Stack, username: str) -> Page:
    context = browser.new_context(viewport={"width": 1280, "height": 1000})
    page = context.new_page()
    page.on("pageerror", lambda exc: SCRIPT_ERRORS.append(f"{username}: {exc}"))
    # A stream on another port than the page's must be allowed by the policy's connect-src.
    page.on(
        "console",
        lambda m: "Content Security Policy" in m.text and SCRIPT_ERRORS.append(m.text),
    )
    login(page, stack.web, username, PASSWORD)
    return page


def _days_shown(calendar: Page) -> list[str]:
    """The dates (ISO) of the columns the week view shows."""
    return calendar.locator(".ec-col-head time[datetime]").evaluate_all(
        "cells => cells.map((cell) => cell.getAttribute('datetime'))"
    )


@pytest.fixture(autouse=True)
def _no_script_errors():
    SCRIPT_ERRORS.clear()
    yield
    assert not SCRIPT_ERRORS, SCRIPT_ERRORS


def test_the_run_page_reconnects_when_the_web_process_restarts_and_ends_completed(
    browser, fault_stack
):
    MobileResourceFactory(agent_url=fault_stack.agent_url)
    # Long enough to be still running when both servers are back: on the slower machine with
    # the suite beside it, 40 s ended while they were starting.
    run_id = Experimenter(fault_stack, "gale").run("mobile-1", ahead_s=4, program_s=80)
    page = _page(browser, fault_stack, "gale")
    page.goto(f"{fault_stack.web}/runs/{run_id}/")
    live = page.locator("#live-status")
    expect(live).to_have_attribute("data-state", "live", timeout=15_000)
    expect(page.locator("#run-state")).to_have_attribute("data-state", "running", timeout=20_000)

    # A deploy restarts both servers: the pages' and API's, and the streams'.
    restarted_at = monotonic()
    fault_stack.kill("streams", signal.SIGTERM)
    fault_stack.kill("web", signal.SIGTERM)
    expect(live).to_have_attribute("data-state", "reconnecting", timeout=15_000)
    expect(live).to_have_text("reconnecting…")
    for name in ("web", "streams"):
        fault_stack.start(name)
    for name in ("web", "streams"):
        fault_stack.wait_ready(name)
    restart_s = monotonic() - restarted_at

    expect(live, f"live again after a restart of {restart_s:.0f} s").to_have_attribute(
        "data-state", "live", timeout=30_000
    )
    expect(page.locator("#run-state")).to_have_attribute("data-state", "completed", timeout=120_000)
    assert fault_stack.agent is not None
    on_agent = fault_stack.agent.get_run(f"run-{run_id}")
    expect(page.locator("#sample-count")).to_have_text(str(on_agent["sample_count"]))
    # Ended: the page stops following.
    expect(live).to_have_attribute("data-state", "off")
    page.context.close()


def test_the_run_page_survives_answers_without_the_run_and_keeps_refreshing(browser, fault_stack):
    """During a deploy the page may get anything: an empty object, an error page, a body cut
    short. Each is reported, and the next read carries on to the run's end."""
    MobileResourceFactory(agent_url=fault_stack.agent_url)
    run_id = Experimenter(fault_stack, "gale").run("mobile-1", ahead_s=3, program_s=6)
    page = _page(browser, fault_stack, "gale")
    bad_answers = [
        {"status": 200, "content_type": "application/json", "body": "{}"},
        {"status": 200, "content_type": "application/json", "body": '{"state": "running"}'},
        {"status": 200, "content_type": "application/json", "body": '{"series": {"t": '},
        {"status": 502, "content_type": "text/html", "body": "<h1>Bad gateway</h1>"},
    ]
    served: list[int] = []

    def answer(route):
        if bad_answers:
            served.append(len(bad_answers))
            route.fulfill(**bad_answers.pop(0))
        else:
            route.continue_()

    page.route(f"**/runs/{run_id}/data.json", answer)
    page.goto(f"{fault_stack.web}/runs/{run_id}/")
    expect(page.locator("#run-progress")).to_contain_text("could not refresh", timeout=15_000)
    expect(page.locator("#run-state")).to_have_attribute("data-state", "completed", timeout=60_000)
    # The page may know "completed" from its first render (a slow machine opens it after the
    # run): its retries after each bad answer (1 s, 2 s, 4 s) read the rest, then the run.
    deadline = monotonic() + 30
    while len(served) < 4 and monotonic() < deadline:
        page.wait_for_timeout(100)  # lets Playwright hand the page's requests to the route
    assert len(served) == 4, "every bad answer should have been read"
    assert fault_stack.agent is not None
    on_agent = fault_stack.agent.get_run(f"run-{run_id}")
    expect(page.locator("#sample-count")).to_have_text(
        str(on_agent["sample_count"]), timeout=30_000
    )
    page.context.close()


def test_the_console_and_the_calendar_show_a_hold_and_new_bookings_without_a_reload(
    browser, fault_stack
):
    robot = MobileResourceFactory(
        name="mobile-2", agent_url=fault_stack.agent2_url, agent_token_name="mobile-2"
    )
    UserFactory(username="root", is_staff=True, is_superuser=True, email="root@example.org")
    UserFactory(username="hana")
    console = _page(browser, fault_stack, "root")
    console.goto(f"{fault_stack.web}/robot/mobile-2/")
    expect(console.locator("#live-status")).to_have_attribute("data-state", "live", timeout=15_000)
    expect(console.locator("#st-link")).to_contain_text("up", timeout=15_000)
    expect(console.locator("#robot-hold")).to_be_hidden()

    calendar = _page(browser, fault_stack, "hana")
    calendar.goto(f"{fault_stack.web}/calendar/")
    expect(calendar.locator("#live-status")).to_have_attribute("data-state", "live", timeout=15_000)
    # Someone else will book tomorrow at ten: show that week and count what it holds once its
    # bookings are in. The week is the one the page opened on by its own clock; when tomorrow
    # is not in it (Sunday, or midnight passed since), the next. (An hour from now could cross
    # midnight, and the week view draws a booking across midnight as two pieces.)
    shown = calendar.locator("#calendar")
    expect(shown).to_have_attribute("data-loading", "false", timeout=15_000)
    tomorrow = timezone.localdate() + timedelta(days=1)
    start = datetime.combine(tomorrow, time(10), tzinfo=ZoneInfo(settings.TIME_ZONE))
    if tomorrow.isoformat() not in _days_shown(calendar):
        calendar.get_by_role("button", name="Next week").click()
        expect(calendar.locator(f".ec-col-head time[datetime='{tomorrow}']")).to_be_attached()
        expect(shown).to_have_attribute("data-loading", "false", timeout=15_000)
    events_before = calendar.locator("#calendar .ec-event").count()

    # Someone else books: the calendar shows it as busy, without a reload.
    node = FixedResourceFactory()
    other = Experimenter(fault_stack, "ivan").session.post(
        f"{fault_stack.web}/api/v1/reservations/",
        json={
            "resources": [node.name],
            "start_at": start.isoformat(),
            "end_at": (start + timedelta(hours=1)).isoformat(),
        },
        timeout=10,
    )
    assert other.status_code == 201, other.text
    expect(calendar.locator("#calendar .ec-event")).to_have_count(events_before + 1, timeout=10_000)

    assert fault_stack.agent2 is not None
    try:
        fault_stack.agent2.stop(user="carol", reason="someone on the roof")
        reason = "emergency stop latched: someone on the roof (by carol)"
        expect(console.locator("#hold-reason")).to_have_text(reason, timeout=15_000)
        expect(console.locator("#robot-hold")).to_be_visible()
        expect(console.locator("#st-estop")).to_contain_text("LATCHED")
        expect(console.locator("#service-button")).to_have_text("Put back in service")
        held = calendar.locator('#robot-holds li[data-resource="mobile-2"]')
        expect(held).to_contain_text("mobile-2 is out of service since", timeout=15_000)
        expect(held).to_contain_text(reason)
    finally:
        fault_stack.agent2.release_stop()

    # Only an admin puts it back, from the console; both pages follow.
    console.locator("#service-form input[name=reason]").fill("roof clear, stop released")
    console.locator("#service-button").click()
    expect(console.locator("#robot-hold")).to_be_hidden(timeout=10_000)
    expect(console.locator("#service-state")).to_have_text("open")
    expect(calendar.locator("#robot-holds")).to_be_hidden(timeout=10_000)
    robot.refresh_from_db()
    assert robot.hold_reason == ""
    console.context.close()
    calendar.context.close()
