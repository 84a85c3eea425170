"""The queue's page in Chromium: ask for a run as soon as possible, see its place and its
estimated start, withdraw it; a request that could never be booked is refused on the form."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from playwright.sync_api import expect

from bookings.models import Reservation, ReservationItem
from portal.queue.allocation import queue_allocate
from portal.queue.campaigns import campaign_create
from portal.queue.models import QueueRequest, RequestState
from portal.queue.results import campaign_results, campaign_runs_completed
from portal.queue.services import queue_request_cancel, queue_request_submit
from tests.browser.conftest import login
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory
from tests.queue.campaign_runs import complete_with_samples

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


def test_a_campaign_page_shows_progress_results_and_chart_and_is_paused_and_downloaded(
    browser, live_server, settings
):
    owner = UserFactory(username="fran")
    MobileResourceFactory()
    settings.QUEUE_LEAD_S = 0
    campaign = campaign_create(
        owner=owner,
        spec={
            "title": "two speeds",
            "robot": "mobile-1",
            "parameters": {"velocity_mps": [0.5, 1.0], "direction": "cw", "duration_s": 3},
            "repeats": 2,
            "earliest_at": "2031-03-04T00:00:00Z",
            "latest_end_at": "2031-03-06T00:00:00Z",
        },
    )
    assert len(queue_allocate(now=datetime(2031, 3, 4, tzinfo=UTC)).booked) == 4
    requests = list(campaign.requests.select_related("reservation__run").order_by("pk"))
    for request in requests[:3]:
        complete_with_samples(request.reservation.run, request.parameters["repeat"])
    groups = campaign_results(campaign_runs_completed(campaign))

    page = browser.new_page(viewport={"width": 1280, "height": 800})
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    login(page, live_server.url, "fran", "correct horse battery")
    page.goto(f"{live_server.url}/queue/")
    page.get_by_test_id("queue-campaigns").get_by_role("link", name="two speeds").click()
    expect(page.get_by_test_id("campaign-progress")).to_contain_text("3 of 4 runs completed")
    rows = page.locator("#campaign-results tbody tr")
    expect(rows).to_have_count(2)
    for row, group in zip(rows.all(), groups, strict=True):
        cell = row.locator('td[data-metric="mean_mps"]')
        velocity = group.metrics["mean_mps"]
        shown = f"{velocity.mean:.3f}" + (f" ± {velocity.sd:.3f}" if velocity.sd else "")
        expect(cell).to_have_text(shown)
    # One line per completed run, drawn.
    assert (
        page.evaluate(
            "Chart.getChart(document.getElementById('campaign-velocity')).data.datasets.length"
        )
        == 3
    )
    expect(page.get_by_test_id("campaign-runs").locator("tbody tr")).to_have_count(4)

    page.get_by_test_id("campaign-pause").click()
    expect(page.locator("p.flash.success")).to_contain_text("Campaign paused")
    expect(page.get_by_test_id("campaign-state")).to_have_text("paused")
    page.get_by_test_id("campaign-resume").click()
    expect(page.get_by_test_id("campaign-state")).to_have_text("active")

    with page.expect_download() as download:
        page.get_by_test_id("campaign-download").click()
    assert download.value.suggested_filename == f"amazing-campaign-{campaign.pk}.zip"
    assert errors == []


def test_a_place_moves_up_on_the_open_page_when_the_request_before_it_is_withdrawn(
    browser, live_server
):
    robot = MobileResourceFactory()
    gil, fran = UserFactory(username="gil"), UserFactory(username="fran")
    later = datetime(2031, 3, 4, tzinfo=UTC)
    first, mine = (
        queue_request_submit(
            owner=who,
            experiment=ExperimentFactory(owner=who),
            robot=robot,
            earliest_at=later,
            latest_end_at=later + timedelta(days=2),
        )
        for who in (gil, fran)
    )
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    # The page's own clock, moved on below to its next reading (no wait on the wall's).
    page.clock.install()
    login(page, live_server.url, "fran", "correct horse battery")
    page.goto(f"{live_server.url}/queue/")
    place = page.get_by_test_id(f"queue-request-{mine.pk}").get_by_test_id("queue-position")
    expect(place).to_have_text("2")
    # Django's test server has no streams: the page polls once its stream has failed. Only
    # then is the poll's timer set, for the fast-forward below to fire.
    expect(page.locator("#live-status")).to_have_attribute("data-state", "reconnecting")
    queue_request_cancel(request=first, by=gil)
    page.clock.fast_forward(16_000)
    expect(place).to_have_text("1")
    assert errors == []
