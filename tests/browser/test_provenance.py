"""A run page in Chromium: how the run was made, its package, and "Run again"."""

from __future__ import annotations

import json
import zipfile
from datetime import timedelta
from pathlib import Path

import pytest
from django.utils import timezone
from playwright.sync_api import expect

from portal.runs.models import Run
from portal.runs.services.reservations import reservation_create
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory
from tests.runs.driving import completed_run

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]


def test_run_again_books_the_next_free_slot_and_links_the_two_runs(browser, live_server, settings):
    settings.RUN_REPEAT_LEAD_S = 60
    fay = UserFactory(username="fay")
    robot = MobileResourceFactory()
    run = completed_run(fay, robot, [(0.5, "cw", 2.0)])
    Run.objects.filter(pk=run.pk).update(
        provenance={
            "format_version": 1,
            "staged": {
                "at": "2026-11-25T10:00:00+00:00",
                "portal_version": "0.1.0",
                "limits": {"max_velocity_mps": 1.5, "max_accel_mps2": 0.5},
                "agent": None,
                "firmware": {"build_id": "bench-7", "protocol_version": 1, "config": {}},
            },
        }
    )
    # The robot is booked from 1 to 3 minutes from now: the repeat's slot is after that.
    start = timezone.now().replace(microsecond=0) + timedelta(minutes=1)
    busy = reservation_create(
        owner=fay,
        resource=robot,
        start_at=start,
        end_at=start + timedelta(minutes=2),
        experiment=ExperimentFactory(owner=fay),
    )
    context = browser.new_context(viewport={"width": 390, "height": 844})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    login(page, live_server.url, "fay", "correct horse battery")
    page.goto(f"{live_server.url}/runs/{run.pk}/")
    section = page.get_by_role("region", name="How this run was made")
    expect(section).to_be_visible()
    expect(section.locator("#provenance-firmware")).to_contain_text("build bench-7")
    expect(section.locator("#provenance-limits")).to_contain_text("run: 1.5 m/s, 0.5 m/s²")
    with page.expect_download() as download_info:
        page.get_by_role("button", name="Download package (zip)").click()
    with zipfile.ZipFile(Path(download_info.value.path())) as package:
        assert json.loads(package.read("datapackage.json"))["amazing"]["run"]["id"] == run.pk

    page.get_by_role("button", name="Run again").click()
    expect(page.get_by_text(f"repeating run {run.pk}")).to_be_visible()
    again = Run.objects.get(repeat_of=run)
    expect(page).to_have_url(f"{live_server.url}/runs/{again.pk}/")
    assert again.start_at == busy.end_at
    assert again.segments == run.segments
    assert again.limits == {"max_velocity_mps": 1.5, "max_accel_mps2": 0.5}
    compare = page.get_by_role("link", name="Compare the two runs")
    expect(compare).to_have_attribute("href", f"/runs/compare/?ids={run.pk},{again.pk}")
    page.screenshot(path=str(SCREENSHOTS / "run-again-phone.png"), full_page=True)
    page.get_by_role("link", name=f"run {run.pk}", exact=True).click()
    expect(page.get_by_text(f"Repeated by run {again.pk}")).to_be_visible()
    assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth + 1")
    assert not errors, errors
    context.close()
