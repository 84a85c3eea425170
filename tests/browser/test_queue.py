"""The queue's page in Chromium: ask for a run as soon as possible, see its place and its
estimated start, withdraw it; a request that could never be booked is refused on the form."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from playwright.sync_api import expect

from bookings.models import Reservation, ReservationItem
from portal.queue.models import QueueRequest, RequestState
from tests.browser.conftest import login
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]


def test_a_request_shows_its_place_and_estimate_and_is_withdrawn(browser, live_server):
    user = UserFactory(username="fran")
    robot = MobileResourceFactory()
    ExperimentFactory(owner=user, title="sweep 0.5")
    # A far-off morning taken until 10:00 UTC (10:00 in Lisbon in March): the estimate.
    day = datetime(2031, 3, 4, tzinfo=UTC)
    taken = Reservation.objects.create(
        owner=UserFactory(username="gil"), start_at=day, end_at=day + timedelta(hours=10)
    )
    ReservationItem.objects.create(
        reservation=taken, resource=robot, start_at=taken.start_at, end_at=taken.end_at
    )
    context = browser.new_context(
        viewport={"width": 375, "height": 812}, timezone_id="Europe/Lisbon"
    )
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    login(page, live_server.url, "fran", "correct horse battery")
    page.goto(f"{live_server.url}/queue/")
    form = page.get_by_test_id("queue-form")
    form.get_by_label("Experiment").select_option(label="sweep 0.5 (6 s)")
    form.get_by_label("Robot").select_option("mobile-1")
    form.get_by_label("No sooner than").fill("2031-03-04T00:00")
    # Ended before it could start: refused on the form, nothing queued.
    form.get_by_label("Ended by").fill("2031-03-04T00:00")
    page.get_by_test_id("queue-submit").click()
    expect(page.get_by_test_id("queue-form")).to_contain_text("no room for the run")
    assert not QueueRequest.objects.exists()

    form = page.get_by_test_id("queue-form")
    form.get_by_label("Experiment").select_option(label="sweep 0.5 (6 s)")
    form.get_by_label("Ended by").fill("2031-03-06T00:00")
    page.get_by_test_id("queue-submit").click()
    queued = QueueRequest.objects.get()
    row = page.get_by_test_id(f"queue-request-{queued.pk}")
    expect(row.get_by_test_id("queue-position")).to_have_text("1")
    expect(row.get_by_test_id("queue-estimate")).to_have_text("2031-03-04 10:00")

    page.get_by_test_id(f"queue-cancel-{queued.pk}").click()
    expect(page.locator("p.flash.success")).to_contain_text(f"Request {queued.pk} withdrawn.")
    queued.refresh_from_db()
    assert queued.state == RequestState.CANCELLED
    assert not errors, errors
    context.close()
