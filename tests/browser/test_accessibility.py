"""Every page, on a whole running system, at a laptop's and a phone's width: no serious or
critical axe-core violation (the npm package, run in Chromium), no page wider than the window,
the top bar on one line at the laptop's width, and nothing a working system never shows.

The system is the real one (``stack``: Celery beat and workers, the web and live-stream
servers, the agent and its simulated robot): a run is booked, runs on the robot and is
collected; fixed nodes are booked on the timeline; the robot stands on the roof. A page
something is found on is photographed (``var/screenshots``); ``make screenshots`` runs this
module with ``SCREENSHOT_DIR=docs/screenshots``, which photographs every page at both widths,
the pictures the README links to, and a page showing the "Runs are not being dispatched"
banner, a live part reconnecting or a roof not available fails it.
"""

from __future__ import annotations

import random
import re
import time
from datetime import timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from django.conf import settings
from django.utils import timezone
from playwright.sync_api import Browser, Page, Request, expect

from basestation.dryrun import dry_run
from basestation.sim.rssi import DEFAULT_NODE_AT, PathLoss, distance_m
from basestation.telemetry.rail import Rail
from bookings.models import Resource
from core.accounts.models import User
from portal.queue.campaigns import campaign_create
from portal.queue.models import RequestState
from portal.queue.services import queue_request_submit
from portal.runs.measurement_files import Points
from portal.runs.measurements import measurement_add
from portal.runs.models import DryRun, Run, SelfCheck, SelfCheckBaseline
from portal.runs.services.reservations import reservation_create
from portal.runs.states import RunState
from tests.browser.conftest import EVERY_PAGE_PHOTOGRAPHED, SCREENSHOTS, login
from tests.factories import FixedResourceFactory, MobileResourceFactory, UserFactory
from tests.integration.experimenter import Experimenter
from tests.integration.stack import Stack

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]

AXE = Path(__file__).resolve().parents[2] / "node_modules" / "axe-core" / "axe.min.js"
VIEWPORTS = {"laptop": {"width": 1280, "height": 800}, "phone": {"width": 375, "height": 812}}
BLOCKING = {"serious", "critical"}
PASSWORD = "correct horse battery"
ADMIN_PAGES = [
    "/admin/",
    "/admin/bookings/resource/",
    "/admin/bookings/resource/add/",
    "/admin/bookings/quotapolicy/",
    "/admin/bookings/blackout/",
    "/admin/runs/run/",
    "/admin/bookings/reservation/",
    "/admin/audit/auditevent/",
    "/admin/accounts/user/",
]


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


# Whether the top bar's items sit on one line: each one's box shares a height with every
# other's (items of different heights are centred on the line, so their tops differ).
TOP_BAR_ONE_LINE = """() => {
  const boxes = [...document.querySelectorAll("header nav > ul > li")].map(
    (item) => item.getBoundingClientRect());
  return Math.max(...boxes.map((b) => b.top)) < Math.min(...boxes.map((b) => b.bottom));
}"""


def _fits_the_window(page: Page, name: str, width: str, found: list[str]) -> None:
    """No page wider than the window: nothing to scroll sideways to."""
    overflow = page.evaluate("document.documentElement.scrollWidth - window.innerWidth")
    if overflow > 1:
        found.append(f"{name} @ {width}: {overflow} px wider than the window")


def _check(settler: Settler, name: str, width: str, found: list[str]) -> None:
    page = settler.page
    settler.wait(name)
    _fits_the_window(page, name, width, found)
    if width == "laptop" and not page.evaluate(TOP_BAR_ONE_LINE):
        found.append(f"{name} @ {width}: the top bar takes more than one line")
    for violation in _axe(page):
        if violation["impact"] in BLOCKING:
            targets = [" ".join(node["target"]) for node in violation["nodes"]][:5]
            found.append(f"{name} @ {width}: {violation['id']} ({violation['impact']}) {targets}")


def _dry_runs(owner: User) -> tuple[DryRun, DryRun]:
    """A dry run the simulator has run (in this process, as its own process would), and one
    still waiting for a place (the places taken by two others running)."""
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
    # Every place on the simulator taken, so the last waits in line. Their start is dated
    # ahead, so that no sweep takes them for lost (DRY_RUN_STALE_S) while pages are checked.
    for slot in range(settings.DRY_RUN_SLOTS):
        DryRun.objects.create(
            **common,
            rail_length_m=120.0,
            state=DryRun.State.RUNNING,
            slot=slot,
            started_at=timezone.now() + timedelta(minutes=10),
        )
    waiting = DryRun.objects.create(**common, rail_length_m=120.0)
    return tried, waiting


# What a working system never shows: the beat-is-gone banner, a live part reconnecting, the
# roof without its robot.
NEVER_SHOWN = re.compile(r"reconnecting|not available", re.IGNORECASE)
RUN_S = 10.0


def _pictured(settler: Settler, name: str, width: str, found: list[str]) -> None:
    """Checked as every page, and as a page of a working system."""
    page = settler.page
    before = len(found)
    if page.locator("#roof").count():
        expect(page.locator("#roof")).to_have_attribute("data-ready", "1", timeout=15_000)
    if page.locator("#st-link").count():
        expect(page.locator("#st-link")).to_contain_text("up", timeout=15_000)
    _check(settler, name, width, found)
    if page.locator("#scheduler-warning").count():
        found.append(f"{name} @ {width}: the 'Runs are not being dispatched' banner")
    shown = NEVER_SHOWN.search(page.locator("body").inner_text())
    if shown:
        found.append(f"{name} @ {width}: the page says {shown.group(0)!r}")
    # Every page for `make screenshots`; in `make test` the pages something was found on (a
    # whole page's picture costs the browser seconds of CPU, two dozen times).
    if EVERY_PAGE_PHOTOGRAPHED or len(found) > before:
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(
            path=str(SCREENSHOTS / f"{name}-{width}.jpg"), type="jpeg", quality=70, full_page=True
        )


def _completed(run_ids: list[int], timeout_s: float = 120.0) -> None:
    """Waits for the runs to be run by the robot and collected."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        states = set(Run.objects.filter(pk__in=run_ids).values_list("state", flat=True))
        if states == {RunState.COMPLETED}:
            return
        time.sleep(0.5)
    raise AssertionError(f"runs {run_ids} not completed in {timeout_s:.0f} s: {states}")


def _measured(run: Run, owner: User) -> None:
    """A synthetic signal strength at each of the run's samples: its measurements section."""
    model, rail, rng = PathLoss(), Rail.default(), random.Random(3)
    samples = list(run.samples.order_by("seq").values_list("t", "track_m"))
    values = [model.sample_dbm(distance_m(rail, DEFAULT_NODE_AT, m), rng) for _, m in samples]
    points = Points(
        times_s=np.array([t.timestamp() for t, _ in samples]),
        columns=["rssi"],
        values=[np.array(values)],
    )
    measurement_add(run=run, by=owner, name="rssi", unit="dBm", points=points)


def _a_campaign(owner: User, completed: list[int]) -> int:
    """A campaign of four runs a month ahead, two of them standing for the day's completed
    runs (their reservations given to its first requests): its page with results and chart."""
    later = timezone.now() + timedelta(days=30)
    campaign = campaign_create(
        owner=owner,
        spec={
            "title": "speed sweep",
            "robot": "mobile-1",
            "parameters": {"velocity_mps": [0.4, 0.8], "direction": "cw", "duration_s": 3},
            "repeats": 2,
            "earliest_at": later.isoformat(),
            "latest_end_at": (later + timedelta(days=2)).isoformat(),
        },
    )
    requests = list(campaign.requests.order_by("pk"))
    for request, run_id in zip(requests, completed, strict=False):
        request.reservation = Run.objects.get(pk=run_id).reservation
        request.state = RequestState.BOOKED
        request.save(update_fields=["reservation", "state"])
    return campaign.pk


def _a_day_on_the_testbed(stack: Stack) -> dict[str, str]:
    """Two runs of ines's run and collected, two dry runs, fixed nodes booked ahead; the
    pages to photograph, by name."""
    MobileResourceFactory(agent_url=stack.agent_url)
    nodes = [FixedResourceFactory(name=f"node-0{n}") for n in (1, 2, 3)]
    ines = Experimenter(stack, "ines")
    sweep = [
        {"velocity_mps": 0.8, "direction": "cw", "duration_s": RUN_S * 0.6},
        {"velocity_mps": 0.4, "direction": "ccw", "duration_s": RUN_S * 0.4},
    ]
    first_start = timezone.now() + timedelta(seconds=4)
    first = ines.run("mobile-1", start=first_start, program_s=RUN_S, segments=sweep)
    second = ines.run(
        "mobile-1",
        start=first_start + timedelta(seconds=RUN_S + 6),
        program_s=RUN_S,
        segments=sweep[:1],
    )
    # The fixed nodes booked in the next hours: the timeline's rows.
    soon = timezone.now() + timedelta(minutes=20)
    for n, node in enumerate(nodes):
        start = soon + timedelta(minutes=25 * n)
        reservation_create(
            owner=ines.user, resource=node, start_at=start, end_at=start + timedelta(minutes=40)
        )
    tried, waiting = _dry_runs(ines.user)
    _completed([first, second])
    _measured(Run.objects.get(pk=first), ines.user)
    # A request waiting in the queue, beyond its horizon: the queue page's table.
    later = timezone.now() + timedelta(days=30)
    queue_request_submit(
        owner=ines.user,
        experiment=Run.objects.get(pk=first).experiment,
        robot=Resource.objects.get(name="mobile-1"),
        earliest_at=later,
        latest_end_at=later + timedelta(days=2),
        hours_from=22,
        hours_to=6,
    )
    campaign = _a_campaign(ines.user, [first, second])
    _self_checks([first, second])
    return {
        "home": "/",
        "experiment": "/experiments/new/",
        "book": "/book/",
        "queue": "/queue/",
        "campaign": f"/campaigns/{campaign}/",
        "calendar": "/calendar/",
        "timeline": "/calendar/timeline/",
        "calendar-feeds": "/calendar/feeds/",
        "run": f"/runs/{first}/",
        "my-runs": "/runs/",
        "compare": f"/runs/compare/?ids={first},{second}",
        "dry-run": f"/dry-runs/{tried.pk}/",
        "dry-run-waiting": f"/dry-runs/{waiting.pk}/",
        "password": "/accounts/password/change/",
        "api-tokens": "/account/tokens/",
        "webhooks": "/account/webhooks/",
        "two-factor": "/accounts/2fa/",
        "api-docs": "/api/docs/",
    }


def _self_checks(run_ids: list[int]) -> None:
    """Two judged self-checks of the robot (a baseline and one held for its battery), on the
    day's runs: the self-checks page's table and trend. How checks are judged is tested in
    tests/runs/test_self_check.py; this is what its page shows."""
    robot = Resource.objects.get(name="mobile-1")
    figures = {
        "rtk_share": 1.0, "tracking_error_mps": 0.02, "accel_mps2": 0.47, "lag_s": 0.45,
        "stop_distance_m": 1.4, "stop_time_s": 2.7, "battery_sag_v": 0.08,
    }  # fmt: skip
    judged = {
        "resource": robot,
        "check_velocity_mps": 1.0,
        "accel_mps2": 0.5,
        "lap_m": 120.0,
        "evaluated_at": timezone.now(),
    }
    passed = SelfCheck.objects.create(
        run=Run.objects.get(pk=run_ids[0]), state=SelfCheck.State.PASSED, figures=figures, **judged
    )
    SelfCheck.objects.create(
        run=Run.objects.get(pk=run_ids[1]),
        state=SelfCheck.State.FAILED,
        figures=dict(figures, battery_sag_v=0.88),
        problems=["battery sag under load 0.88 V is over 0.50 V"],
        baseline=figures,
        **judged,
    )
    SelfCheckBaseline.objects.create(resource=robot, figures=figures, source=passed)


STAFF_PAGES = {
    "approvals": "/approvals/",
    "robot-console": "/robot/mobile-1/",
    "robot-self-checks": "/robot/mobile-1/self-checks/",
    "usage": "/usage/",
    "scheduler-link": "/scheduler-link/",
}


def _visit(
    browser: Browser, web: str, user: str | None, pages: dict[str, str], width: str
) -> list[str]:
    found: list[str] = []
    context = browser.new_context(viewport=VIEWPORTS[width], timezone_id="Europe/Lisbon")
    page = context.new_page()
    settler = Settler(page)
    if user is None:
        page.goto(f"{web}/accounts/login/")
        _pictured(settler, "sign-in", width, found)
        context.close()
        return found
    login(page, web, user, PASSWORD)
    for name, path in pages.items():
        response = page.goto(f"{web}{path}")
        assert response is not None, path
        assert response.status == 200, path
        _pictured(settler, name, width, found)
        if name == "calendar":
            # Its hours scroll, with or without a booking to tab to: reachable by keyboard,
            # and opened at the morning.
            hours = page.locator("#calendar .ec-main")
            expect(hours).to_have_attribute("role", "region")
            expect(hours).to_have_attribute("tabindex", "0")
            assert hours.evaluate("box => box.scrollHeight > box.clientHeight")
            assert hours.evaluate("box => box.scrollTop > 0")
    if user == "ada":
        # The admin's pages (Django's own markup and styles): as wide as the window too.
        for path in ADMIN_PAGES:
            response = page.goto(f"{web}{path}")
            assert response is not None, path
            assert response.status == 200, path
            settler.wait(path)
            _fits_the_window(page, path, width, found)
    context.close()
    return found


# A bound that only ends a hang: beside a busy suite on the slower machine, the set-up and
# the pages took 312 s together (300 s is the suite's default bound).
@pytest.mark.timeout(600)
def test_every_page_of_a_working_system_at_a_laptops_and_a_phones_width(browser, stack):
    assert AXE.exists(), "axe-core is missing: `make setup` installs it from npm"
    UserFactory(username="ada", is_staff=True, is_superuser=True)
    pages = _a_day_on_the_testbed(stack)
    found: list[str] = []
    for width in VIEWPORTS:
        found += _visit(browser, stack.web, None, {}, width)
        found += _visit(browser, stack.web, "ines", pages, width)
        found += _visit(browser, stack.web, "ada", STAFF_PAGES, width)
    assert not found, "\n".join(found)
