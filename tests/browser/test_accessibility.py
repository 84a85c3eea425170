"""Every page passes axe-core (the npm package, run in Chromium) at a laptop's and a phone's
width with no serious or critical violation, and is photographed at both widths.

``make screenshots`` runs this module with ``SCREENSHOT_DIR=docs/screenshots``: the pictures
the README links to.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest
from django.utils import timezone
from playwright.sync_api import Page, Request, expect

from basestation.dryrun import dry_run
from core.accounts.models import User
from portal.runs.models import DryRun
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import MobileResourceFactory, UserFactory
from tests.runs.driving import completed_run

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]

AXE = Path(__file__).resolve().parents[2] / "node_modules" / "axe-core" / "axe.min.js"
VIEWPORTS = {"laptop": {"width": 1280, "height": 800}, "phone": {"width": 375, "height": 812}}
BLOCKING = {"serious", "critical"}
PASSWORD = "correct horse battery"


def _axe(page: Page) -> list[dict[str, Any]]:
    """axe-core's violations of WCAG 2.x A and AA on the page as it stands. The library is
    evaluated through the browser's debugging protocol, which the page's content security
    policy does not govern (the portal never serves it)."""
    if not page.evaluate("typeof window.axe !== 'undefined'"):
        page.evaluate(AXE.read_text())
    result: dict[str, Any] = page.evaluate(
        """() => axe.run(document, {
            runOnly: {type: "tag", values: ["wcag2a", "wcag2aa", "wcag21a", "wcag21aa"]},
            resultTypes: ["violations"],
        })"""
    )
    return list(result["violations"])


# Each page's document notes when it last changed (the script runs before the page's own).
WATCH_CHANGES = """
window.__changedAt = performance.now();
new MutationObserver(() => { window.__changedAt = performance.now(); }).observe(
  document, {subtree: true, childList: true, attributes: true, characterData: true});
"""
QUIET_MS = 400
SETTLE_S = 30.0


class Settler:
    """Waits until a page has drawn what it fetches after load (charts, calendars, live
    parts): no request in flight but its streams, nothing still loading, and the document
    unchanged for ``QUIET_MS``. Not Playwright's "networkidle": a page that polls while its
    stream is away (the test server has none) may never be idle for 500 ms when the machine
    is slow, yet it is settled between two polls."""

    def __init__(self, page: Page) -> None:
        self.page = page
        self.in_flight: set[Request] = set()
        page.context.add_init_script(WATCH_CHANGES)
        page.on("request", self._started)
        page.on("requestfinished", self._ended)
        page.on("requestfailed", self._ended)

    def _started(self, request: Request) -> None:
        if request.resource_type != "eventsource":
            self.in_flight.add(request)

    def _ended(self, request: Request) -> None:
        self.in_flight.discard(request)

    def wait(self, name: str) -> None:
        self.page.wait_for_load_state("load")
        deadline = time.monotonic() + SETTLE_S
        while time.monotonic() < deadline:
            quiet_ms = self.page.evaluate(
                """() => document.readyState === "complete"
                    && !document.querySelector('[data-loading="true"]')
                    && window.__changedAt !== undefined
                    ? performance.now() - window.__changedAt : 0"""
            )
            if not self.in_flight and quiet_ms >= QUIET_MS:
                return
            self.page.wait_for_timeout(100)
        raise AssertionError(
            f"{name} did not settle in {SETTLE_S:.0f} s: {len(self.in_flight)} requests "
            f"in flight ({sorted(r.url for r in self.in_flight)[:3]})"
        )


def _check(settler: Settler, name: str, width: str, found: list[str]) -> None:
    page = settler.page
    settler.wait(name)
    for violation in _axe(page):
        if violation["impact"] in BLOCKING:
            targets = [" ".join(node["target"]) for node in violation["nodes"]][:5]
            found.append(f"{name} @ {width}: {violation['id']} ({violation['impact']}) {targets}")
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(
        path=str(SCREENSHOTS / f"{name}-{width}.jpg"), type="jpeg", quality=70, full_page=True
    )


def _dry_runs(owner: User) -> tuple[DryRun, DryRun]:
    """A dry run the simulator has run (in this process, as its own process would), and one
    still waiting for a place."""
    segments = [
        {"velocity_mps": 0.8, "direction": "cw", "duration_s": 20.0},
        {"velocity_mps": 0.4, "direction": "ccw", "duration_s": 10.0},
    ]
    limits = {"max_velocity_mps": 1.0, "max_accel_mps2": 0.5}
    result = dry_run(segments, **limits, rail_length_m=120.0)
    common = {"owner": owner, "title": "sweep", "segments": segments, "limits": limits}
    tried = DryRun.objects.create(
        **common,
        rail_length_m=120.0,
        state=DryRun.State.COMPLETED,
        samples=result["samples"],
        started_at=timezone.now(),
        ended_at=timezone.now(),
    )
    waiting = DryRun.objects.create(**common, rail_length_m=120.0)
    return tried, waiting


@pytest.mark.parametrize("width", list(VIEWPORTS))
def test_every_page_passes_axe_at_a_laptops_and_a_phones_width(browser, live_server, width):
    assert AXE.exists(), "axe-core is missing: `make setup` installs it from npm"
    admin = UserFactory(username="ada", is_staff=True, is_superuser=True)
    robot = MobileResourceFactory()
    first = completed_run(admin, robot, [(1.0, "cw", 40.0), (0.5, "ccw", 20.0)])
    second = completed_run(admin, MobileResourceFactory(name="mobile-2"), [(0.8, "cw", 30.0)])
    tried, waiting = _dry_runs(admin)
    found: list[str] = []
    context = browser.new_context(viewport=VIEWPORTS[width], timezone_id="Europe/Lisbon")
    page = context.new_page()
    settler = Settler(page)

    page.goto(f"{live_server.url}/accounts/login/")
    _check(settler, "sign-in", width, found)
    login(page, live_server.url, "ada", PASSWORD)
    pages = {
        "home": "/",
        "experiment": "/experiments/new/",
        "book": "/book/",
        "calendar": "/calendar/",
        "timeline": "/calendar/timeline/",
        "calendar-feeds": "/calendar/feeds/",
        "run": f"/runs/{first.pk}/",
        "my-runs": "/runs/",
        "compare": f"/runs/compare/?ids={first.pk},{second.pk}",
        "dry-run": f"/dry-runs/{tried.pk}/",
        "dry-run-waiting": f"/dry-runs/{waiting.pk}/",
        "approvals": "/approvals/",
        "robot-console": f"/robot/{robot.name}/",
        "usage": "/usage/",
        "scheduler-link": "/scheduler-link/",
        "password": "/accounts/password/change/",
        "api-tokens": "/account/tokens/",
        "two-factor": "/accounts/2fa/",
    }
    for name, path in pages.items():
        response = page.goto(f"{live_server.url}{path}")
        assert response is not None, path
        assert response.status == 200, path
        _check(settler, name, width, found)
        if name == "calendar":
            # Its hours scroll, with or without a booking to tab to: reachable by keyboard,
            # and opened at the morning.
            hours = page.locator("#calendar .fc-view-harness")
            expect(hours).to_have_attribute("role", "region")
            expect(hours).to_have_attribute("tabindex", "0")
            assert hours.evaluate("box => box.scrollHeight > box.clientHeight")
            assert hours.evaluate("box => box.scrollTop > 0")
    context.close()
    assert not found, "\n".join(found)
