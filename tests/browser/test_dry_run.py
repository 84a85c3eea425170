"""A dry run in Chromium against the real stack: from the experiment page to the simulated
run's charts and statistics, run by the real worker in the simulator's own process, while the
robot's real base station is never asked to run anything."""

from __future__ import annotations

import re

import pytest
from playwright.sync_api import expect

from portal.experiments.models import Experiment
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import MobileResourceFactory, UserFactory
from tests.runs.driving import ramped_travel

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]

PROGRAM = [(0.8, "cw", 6.0), (0.4, "ccw", 4.0)]
ACCEL_MPS2 = 0.5


def test_try_on_the_simulator_from_the_builder_shows_the_simulated_run(browser, stack):
    MobileResourceFactory(
        agent_url=stack.agent_url, max_velocity_mps=1.0, max_accel_mps2=ACCEL_MPS2
    )
    UserFactory(username="kim")
    context = browser.new_context(viewport={"width": 1280, "height": 1000})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    login(page, stack.web, "kim", "correct horse battery")

    page.goto(f"{stack.web}/experiments/new/")
    # A new experiment is saved first: the simulator runs what was saved.
    expect(page.locator("#dry-run-start")).to_have_count(0)
    page.get_by_label("Title").fill("slow sweep")
    rows = page.locator("#segments tbody tr")
    for i, (mps, direction, duration_s) in enumerate(PROGRAM):
        rows.nth(i).get_by_label("velocity in m/s").fill(str(mps))
        rows.nth(i).get_by_label("direction").select_option(direction)
        rows.nth(i).get_by_label("duration in s").fill(str(duration_s))
    page.get_by_role("button", name="Save experiment").click()
    expect(page.locator("p.flash.success")).to_contain_text("saved")
    experiment = Experiment.objects.get(title="slow sweep")

    page.goto(f"{stack.web}/experiments/{experiment.pk}/")
    page.get_by_role("button", name="Try on the simulator").click()
    expect(page).to_have_url(re.compile(r"/dry-runs/\d+/$"))
    expect(page.get_by_test_id("simulated")).to_have_text("simulated")
    state = page.locator("#run-state")
    expect(state).to_have_attribute("data-state", "completed", timeout=60_000)

    # The run page's charts and statistics, of the simulated robot's samples.
    page.wait_for_function(
        "() => Chart.getChart('velocity-chart') &&"
        " Chart.getChart('velocity-chart').data.datasets[1].data.length > 100"
    )
    distance_m, _ = ramped_travel(PROGRAM, ACCEL_MPS2)
    shown = page.locator("#distance").inner_text()
    assert float(shown.removesuffix(" m")) == pytest.approx(distance_m, abs=0.1)
    expect(page.locator("#segment-stats tbody tr")).to_have_count(len(PROGRAM))
    page.screenshot(path=str(SCREENSHOTS / "dry-run.png"), full_page=True)

    # The robot's base station was never asked to run anything.
    assert stack.agent is not None
    assert stack.agent.list_runs() == []
    assert not errors, errors
    context.close()
