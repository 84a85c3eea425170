"""In Chromium against the real stack: a booking made through the lease API shows on its
owner's home page with "Attach an experiment"; the owner attaches one on that page, lands on
its run page, and the robot runs it to the end."""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from bookings.choices import BookedVia
from bookings.models import Reservation
from tests.browser.conftest import login
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory
from tests.integration.experimenter import lease_robot_session

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]


def test_the_owner_attaches_an_experiment_on_the_page_and_it_runs(browser, stack):
    MobileResourceFactory(agent_url=stack.agent_url)
    owner = UserFactory(username="erin")
    ExperimentFactory(
        owner=owner,
        title="attached later",
        segments=[{"velocity_mps": 0.5, "direction": "cw", "duration_s": 3.0}],
    )
    context = browser.new_context(viewport={"width": 375, "height": 812})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    # Signed in first: on a busy machine the sign-in alone took 7 s of a booking's lead.
    login(page, stack.web, "erin", "correct horse battery")
    # Far enough ahead to attach first.
    lease = lease_robot_session(stack.web, "erin", ahead_s=25)
    assert lease.status_code == 200, lease.text
    reservation = Reservation.objects.get(booked_via=BookedVia.SCHEDULER)
    page.reload()
    page.get_by_role("link", name="Attach an experiment").click()
    expect(page).to_have_url(f"{stack.web}/reservations/{reservation.pk}/attach/")
    page.get_by_label("Experiment").select_option(label="attached later (3 s)")
    page.get_by_role("button", name="Attach").click()
    expect(page.locator("p.flash.success")).to_contain_text("mobile-1 will run “attached later”")
    expect(page).to_have_url(f"{stack.web}/runs/{reservation.run.pk}/")
    expect(page.locator("#run-state")).to_have_attribute("data-state", "completed", timeout=60_000)
    assert stack.agent is not None
    on_agent = stack.agent.get_run(f"run-{reservation.run.pk}")
    expect(page.locator("#sample-count")).to_have_text(str(on_agent["sample_count"]))
    assert not errors, errors
    context.close()
