"""The booking calendar in Chromium: drag a slot, choose an experiment, confirm, see, cancel."""

from __future__ import annotations

import pytest
from playwright.sync_api import Page, expect

from bookings.models import Reservation
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import (
    ExperimentFactory,
    FixedResourceFactory,
    MobileResourceFactory,
    UserFactory,
)

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]


def _drag(page: Page, date: str, from_time: str, to_time: str) -> None:
    """Press just below from_time's line in the day's column, let go just above to_time's.

    The hours' labels (the column on the left) are centred on their lines."""
    page.locator(f".ec-sidebar time[datetime$='T{to_time}']").scroll_into_view_if_needed()
    column = page.locator(f".ec-col-head:has(time[datetime='{date}'])").bounding_box()
    top = page.locator(f".ec-sidebar time[datetime$='T{from_time}']").bounding_box()
    bottom = page.locator(f".ec-sidebar time[datetime$='T{to_time}']").bounding_box()
    assert column
    assert top
    assert bottom
    x = column["x"] + column["width"] / 2
    top_y = top["y"] + top["height"] / 2
    bottom_y = bottom["y"] + bottom["height"] / 2
    page.mouse.move(x, top_y + 4)
    page.mouse.down()
    page.mouse.move(x, (top_y + bottom_y) / 2, steps=5)
    page.mouse.move(x, bottom_y - 4, steps=5)
    page.mouse.up()


def test_book_by_dragging_on_the_calendar_then_cancel(browser, live_server):
    user = UserFactory(username="fran")
    MobileResourceFactory()
    FixedResourceFactory(name="node-01")
    ExperimentFactory(owner=user, title="loop test")
    context = browser.new_context(
        viewport={"width": 1280, "height": 1000}, timezone_id="Europe/Lisbon"
    )
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.on("dialog", lambda dialog: dialog.accept())

    login(page, live_server.url, "fran", "correct horse battery")
    page.get_by_role("link", name="Calendar").click()
    expect(page.get_by_test_id("calendar-zone")).to_have_text("Europe/Lisbon")
    page.get_by_role("button", name="Next week").click()  # next week: every slot is in the future
    wednesday = page.locator(".ec-col-head time[datetime]").nth(2).get_attribute("datetime")
    _drag(page, wednesday, "10:00:00", "11:00:00")

    dialog = page.locator("#booking-dialog")
    expect(dialog).to_be_visible()
    expect(dialog.get_by_label("Start")).to_have_value(f"{wednesday}T10:00")
    expect(dialog.get_by_label("End")).to_have_value(f"{wednesday}T11:00")
    dialog.get_by_label("resources").select_option(["mobile-1"])
    # The live check applies booking's rules: the robot needs a program.
    expect(page.locator("#booking-feedback")).to_contain_text(
        "Choose the experiment the robot will run."
    )
    dialog.get_by_label("experiment").select_option(label="loop test (6 s)")
    expect(page.locator("#booking-feedback")).to_contain_text("Free, and within your quota")
    dialog.get_by_role("button", name="Confirm booking").click()
    expect(dialog).to_be_hidden()
    event = page.locator(".ec-event", has_text="loop test")
    expect(event).to_be_visible()
    reservation = Reservation.objects.get()
    assert reservation.run.experiment.title == "loop test"
    page.screenshot(path=str(SCREENSHOTS / "calendar.png"))

    event.click()
    expect(page.locator("#event-dialog")).to_be_visible()
    page.get_by_role("button", name="Cancel booking").click()
    expect(page.locator(".ec-event", has_text="loop test")).to_have_count(0)
    reservation.refresh_from_db()
    assert reservation.state == "cancelled"
    assert not errors, errors
    context.close()


def test_the_calendar_explains_a_refusal_in_the_dialog(browser, live_server):
    from bookings.models import QuotaPolicy

    user = UserFactory(username="gil")
    FixedResourceFactory(name="node-01")
    QuotaPolicy.objects.create(name="Short slots", user=user, max_length_s=1800)
    context = browser.new_context(
        viewport={"width": 1280, "height": 1000}, timezone_id="Europe/Lisbon"
    )
    page = context.new_page()
    login(page, live_server.url, "gil", "correct horse battery")
    page.goto(f"{live_server.url}/calendar/")
    page.get_by_role("button", name="Next week").click()
    day = page.locator(".ec-col-head time[datetime]").nth(1).get_attribute("datetime")
    _drag(page, day, "09:00:00", "10:00:00")
    dialog = page.locator("#booking-dialog")
    dialog.get_by_label("resources").select_option(["node-01"])
    expect(page.locator("#booking-feedback")).to_contain_text(
        "“Short slots” allows reservations of at most 30 min"
    )
    # The refusal's text is already there from the live check: wait for the booking's own
    # answer, or the test could end (and empty the database) under the request.
    with page.expect_response("**/api/v1/reservations/") as refused:
        dialog.get_by_role("button", name="Confirm booking").click()
    assert refused.value.status >= 400
    expect(page.locator("#booking-feedback")).to_contain_text("at most 30 min")
    expect(dialog).to_be_visible()
    # A time the clocks skip is refused before anything is asked, saying why (the portal's
    # rule, core/wall_clock.py); a time they pass twice is booked as the first of the two.
    start = dialog.get_by_label("Start")
    start.fill("2027-03-28T01:30")
    expect(page.locator("#booking-feedback")).to_have_text(
        "01:30 does not exist on 28 March 2027 in Europe/Lisbon: "
        "clocks go forward from 01:00 to 02:00."
    )
    start.fill("2027-10-31T01:30")
    dialog.get_by_label("End").fill("2027-10-31T01:50")
    expect(page.locator("#booking-feedback")).to_contain_text(
        "01:30 is the first of the two that night (UTC+01:00)."
    )
    assert not Reservation.objects.exists()
    context.close()
