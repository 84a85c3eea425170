"""The pages in a real browser (Debian's Chromium via Playwright) against the real stack."""

from __future__ import annotations

from datetime import UTC, timedelta
from pathlib import Path

import pytest
from django.conf import settings
from django.utils import timezone
from playwright.sync_api import Page, expect
from playwright.sync_api import TimeoutError as PlaywrightTimeoutError

from portal.runs.models import RunEvent
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import MobileResourceFactory, UserFactory
from tests.integration.stack import running_stack
from tests.runs.driving import completed_run

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]


def _no_horizontal_scroll(page: Page, timeout_ms: float = 15_000) -> bool:
    """Whether the page, once its scripts have laid it out (a calendar sizes itself after
    the load event, later on a busy machine), fits the window's width."""
    try:
        page.wait_for_function(
            # A function, not an expression: Playwright evaluates an expression with eval() on
            # each poll, which the pages' Content Security Policy refuses.
            "() => document.documentElement.scrollWidth <= window.innerWidth + 1",
            timeout=timeout_ms,
        )
    except PlaywrightTimeoutError:
        return False
    return True


@pytest.fixture
def stack_in_utc(tmp_path):
    """The stack with the testbed's zone UTC. The test books "in six seconds" by typing a
    wall-clock time, as a researcher does; in Europe/Lisbon, during the second pass of the
    hour the clocks go back, that time names the first pass, an hour ago."""
    with running_stack(
        tmp_path / "var",
        broker_url=settings.CELERY_BROKER_URL,
        extra_env={"TESTBED_TIME_ZONE": "UTC"},
    ) as running:
        yield running


def test_an_experimenter_writes_books_and_watches_a_run(browser, stack_in_utc):
    stack = stack_in_utc
    MobileResourceFactory(agent_url=stack["agent_url"])
    UserFactory(username="dana")  # password: see factories
    web = stack["web"]
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    context = browser.new_context(viewport={"width": 1280, "height": 900}, timezone_id="UTC")
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.on("response", lambda r: r.status >= 400 and errors.append(f"{r.status} {r.url}"))

    login(page, web, "dana", "correct horse battery")
    page.get_by_role("link", name="New experiment").first.click()
    page.get_by_label("Title").fill("browser lap")
    # Three rows are offered; add a fourth with the button, fill two, leave the rest empty.
    page.get_by_role("button", name="Add segment").click()
    expect(page.locator("#segments tbody tr")).to_have_count(4)
    rows = page.locator("#segments tbody tr")
    rows.nth(0).get_by_label("velocity in m/s").fill("9")
    rows.nth(0).get_by_label("duration in s").fill("2")
    page.get_by_role("button", name="Save experiment").click()
    # Too fast for the robot: the form says which segment and why, and keeps the input.
    expect(page.get_by_role("alert")).to_contain_text(
        "Segment 0: velocity 9 m/s is faster than every robot you may book"
    )
    rows = page.locator("#segments tbody tr")
    expect(rows.nth(0).get_by_label("velocity in m/s")).to_have_value("9")
    rows.nth(0).get_by_label("velocity in m/s").fill("0.7")
    rows.nth(1).get_by_label("velocity in m/s").fill("0.3")
    rows.nth(1).get_by_label("direction").select_option("ccw")
    rows.nth(1).get_by_label("duration in s").fill("2")
    page.get_by_role("button", name="Save experiment").click()
    expect(page.get_by_text("Experiment “browser lap” saved.")).to_be_visible()

    # Saved, the page offers the next steps: trying it on the simulator, and booking it.
    expect(page.get_by_role("button", name="Try on the simulator")).to_be_visible()
    page.locator("#book-experiment").click()
    expect(page.get_by_text("Times are in UTC.")).to_be_visible()
    start = (timezone.now() + timedelta(seconds=6)).astimezone(UTC).replace(microsecond=0)
    # The robot is ticked: the experiment fits it (and the link named the experiment).
    expect(page.get_by_label("mobile-1 (robot)")).to_be_checked()
    page.get_by_label("Start").fill(start.strftime("%Y-%m-%dT%H:%M:%S"))
    page.get_by_label("End").fill((start + timedelta(seconds=8)).strftime("%Y-%m-%dT%H:%M:%S"))
    page.get_by_role("button", name="Book").click()

    expect(page.get_by_role("heading", name="browser lap")).to_be_visible()
    try:
        expect(page.locator("#run-state")).to_have_attribute(
            "data-state", "completed", timeout=60_000
        )
    except AssertionError:
        # Say why the run did not complete, from its history and the processes' own words.
        history = list(RunEvent.objects.order_by("at").values_list("to_state", "reason"))
        pytest.fail(f"the run's history: {history}\n{stack.output(120)}")
    expect(page.locator("#sample-count")).not_to_have_text("0")
    for chart, dataset in (("velocity-chart", 1), ("position-chart", 0), ("battery-chart", 0)):
        points = page.evaluate(f"Chart.getChart('{chart}').data.datasets[{dataset}].data.length")
        assert points >= 60, chart
    # The tables are redrawn as samples arrive: both segments once the run has ended.
    expect(page.locator("#segment-stats tbody tr")).to_have_count(2)

    # Where was the robot half a metre into its first segment, and how fast?
    start_m = page.evaluate("Chart.getChart('position-chart').data.datasets[0].data[0].y")
    # The robot waits at the origin, where GPS noise can put it just below the rail's end.
    rail_m = float(page.locator("#pass-form").get_attribute("data-rail-length-m"))
    at_m = f"{(start_m + 0.5) % rail_m:.1f}"
    page.get_by_label("Position along the rail (m)").fill(at_m)
    page.get_by_role("button", name="Show passes").click()
    expect(page.locator("#passes-title")).to_contain_text(f"At {at_m} m")
    first_pass = page.locator("#passes tbody tr").first
    expect(first_pass.locator("td").nth(3)).to_have_text("cw")
    assert 0.3 < float(first_pass.locator("td").nth(4).inner_text()) <= 0.8
    page.screenshot(path=str(SCREENSHOTS / "run-page.png"), full_page=True)
    page.get_by_label("Position along the rail (m)").fill("100000")
    page.get_by_role("button", name="Show passes").click()
    expect(page.locator("#pass-error")).to_contain_text("from 0 up to")
    page.go_back()
    expect(page.locator("#passes tbody tr").first).to_be_visible()

    with page.expect_download() as download_info:
        page.get_by_role("button", name="Download CSV").click()
    csv_text = Path(download_info.value.path()).read_text()
    assert csv_text.splitlines()[0].startswith("seq,t,segment,commanded_velocity_mps")
    assert len(csv_text.splitlines()) == int(page.locator("#sample-count").inner_text()) + 1
    assert not errors, errors
    context.close()


@pytest.mark.parametrize(
    "viewport", [{"width": 390, "height": 844}, {"width": 1280, "height": 800}]
)
def test_pages_fit_a_phone_and_a_laptop(browser, live_server, viewport):
    eve = UserFactory(username="eve")
    run = completed_run(eve, MobileResourceFactory(), [(1.0, "cw", 150.0), (0.5, "ccw", 30.0)])
    context = browser.new_context(viewport=viewport)
    page = context.new_page()
    failed: list[str] = []
    page.on("response", lambda r: r.status >= 400 and failed.append(f"{r.status} {r.url}"))
    login(page, live_server.url, "eve", "correct horse battery")
    run_page = f"/runs/{run.pk}/?at_m=50"
    for path in ("/", "/experiments/new/", "/book/", "/calendar/", "/calendar/feeds/", run_page):
        page.goto(f"{live_server.url}{path}")
        assert page.evaluate("getComputedStyle(document.body).fontFamily") != "", path
        assert _no_horizontal_scroll(page), f"{path} scrolls sideways at {viewport}"
    # The run page's tables scroll inside their own box on a phone; its passes are there.
    page.goto(f"{live_server.url}{run_page}")
    expect(page.locator("#passes tbody tr")).to_have_count(3)
    page.screenshot(path=str(SCREENSHOTS / f"run-{viewport['width']}.png"), full_page=True)
    page.goto(f"{live_server.url}/")
    page.screenshot(path=str(SCREENSHOTS / f"home-{viewport['width']}.png"))
    assert not failed, failed
    context.close()


def test_no_page_breaks_the_content_security_policy(browser, live_server):
    """Every page of a researcher and of an admin, the API docs included, runs under the
    policy with nothing refused: no inline script, nothing from elsewhere."""
    admin = UserFactory(username="zoe", is_staff=True, is_superuser=True)
    robot = MobileResourceFactory()
    run = completed_run(admin, robot, [(1.0, "cw", 20.0)])
    context = browser.new_context()
    page = context.new_page()
    refused: list[str] = []
    page.on(
        "console",
        lambda m: "Content Security Policy" in m.text and refused.append(f"{page.url}: {m.text}"),
    )
    login(page, live_server.url, "zoe", "correct horse battery")
    for path in (
        "/",
        "/experiments/new/",
        "/book/",
        "/calendar/",
        "/calendar/feeds/",
        f"/runs/{run.pk}/",
        "/approvals/",
        f"/robot/{robot.name}/",
        "/usage/",
        "/scheduler-link/",
        "/accounts/password/change/",
        "/account/tokens/",
        "/account/webhooks/",
        "/accounts/2fa/",
        "/accounts/2fa/recovery-codes/",
    ):
        response = page.goto(f"{live_server.url}{path}")
        assert response is not None, path
        assert response.status == 200, path
        assert "script-src 'self'" in (response.headers.get("content-security-policy") or "")
        page.wait_for_load_state("load")
    page.goto(f"{live_server.url}/api/docs/")
    # Swagger UI draws the whole schema in the page: seconds on a busy machine. What counts
    # here is that it drew under the policy, not how fast.
    expect(page.locator(".swagger-ui .info .title")).to_be_visible(timeout=60_000)
    assert not refused, refused
    context.close()
