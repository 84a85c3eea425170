"""A finished run's page in Chromium reads the run until a read succeeds: no push will come to
make it read again, so a failed read (a deploy, a proxy's error page) is retried by itself."""

from __future__ import annotations

import re
from datetime import timedelta

import pytest
from django.utils import timezone
from playwright.sync_api import Route, expect

from portal.runs.models import Sample
from portal.runs.services.reservations import reservation_create
from tests.browser.conftest import login
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory
from tests.runs.driving import completed_run

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]


def test_a_finished_runs_page_reads_it_again_after_a_failed_read(browser, live_server):
    owner = UserFactory(username="hal")
    run = completed_run(owner, MobileResourceFactory(), [(0.5, "cw", 2.0)])
    bad_answers = [
        {"status": 502, "content_type": "text/html", "body": "<h1>Bad gateway</h1>"},
        {"status": 200, "content_type": "application/json", "body": '{"series": {"t": '},
    ]
    served: list[int] = []

    def answer(route: Route) -> None:
        if bad_answers:
            served.append(len(bad_answers))
            route.fulfill(**bad_answers.pop(0))
        else:
            route.continue_()

    context = browser.new_context(viewport={"width": 1280, "height": 900})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    login(page, live_server.url, "hal", "correct horse battery")
    page.route(f"**/runs/{run.pk}/data.json", answer)
    page.goto(f"{live_server.url}/runs/{run.pk}/")
    # The first read fails and says so; the retries read the run without a reload: the
    # charts (drawn only from a read) fill and the message goes.
    progress = page.locator("#run-progress")
    expect(progress).to_contain_text("could not refresh", timeout=15_000)
    page.wait_for_function(
        "() => Chart.getChart('velocity-chart').data.datasets[0].data.length > 0",
        timeout=30_000,
    )
    expect(progress).not_to_contain_text("could not refresh")
    expect(page.locator("#run-state")).to_have_attribute("data-state", "completed")
    assert served == [2, 1], "both bad answers were read before the good one"
    assert not errors, errors
    context.close()


def test_a_battery_that_flickers_by_one_reading_step_is_drawn_as_small_steps(browser, live_server):
    """Charts show noise as noise: the battery's line holds each reading until the next, and
    its axis spans at least a volt, so an 0.08 V flicker is a small step, not a barcode."""
    owner = UserFactory(username="ida")
    run = completed_run(owner, MobileResourceFactory(), [(0.5, "cw", 2.0)])
    samples = list(Sample.objects.filter(run=run))
    for sample in samples:
        sample.battery_v = 50.0 + 0.08 * (sample.seq % 2)
    Sample.objects.bulk_update(samples, ["battery_v"])

    context = browser.new_context(viewport={"width": 1280, "height": 900})
    page = context.new_page()
    login(page, live_server.url, "ida", "correct horse battery")
    page.goto(f"{live_server.url}/runs/{run.pk}/")
    page.wait_for_function(
        "() => Chart.getChart('battery-chart').data.datasets[0].data.length > 0", timeout=30_000
    )
    drawn = page.evaluate(
        """() => {
            const chart = Chart.getChart('battery-chart');
            const values = chart.data.datasets[0].data.map((p) => p.y);
            return {stepped: chart.data.datasets[0].stepped, low: chart.scales.y.min,
                    high: chart.scales.y.max, values: [Math.min(...values), Math.max(...values)]};
        }"""
    )
    assert drawn["stepped"] is True
    assert drawn["values"] == [50.0, 50.08]
    assert drawn["high"] - drawn["low"] >= 1.0
    assert drawn["low"] <= 50.0
    assert drawn["high"] >= 50.08
    context.close()


def test_a_run_not_yet_started_counts_down_and_offers_no_repeat(browser, live_server):
    owner = UserFactory(username="jan")
    start = timezone.now() + timedelta(hours=2)
    run = reservation_create(
        owner=owner,
        resource=MobileResourceFactory(),
        start_at=start,
        end_at=start + timedelta(minutes=5),
        experiment=ExperimentFactory(owner=owner),
    ).run
    context = browser.new_context(viewport={"width": 375, "height": 800})
    page = context.new_page()
    login(page, live_server.url, "jan", "correct horse battery")
    page.goto(f"{live_server.url}/runs/{run.pk}/")
    expect(page.locator("#run-countdown-left")).to_have_text(
        re.compile(r"^ · in (1 h 59 min|2 h 0 min)$")
    )
    expect(page.locator("#run-again")).to_have_count(0)
    context.close()
