"""Hold-to-drive on the admin console in Chromium, against the real agent and simulated robot:
the robot moves only while held; letting go commands 0 at once (again after a repeat that was
still on its way) and the robot ramps down to a stand; a page that vanishes mid-hold, its stop
lost too, is stopped by the base station when the command's TTL runs out. (How fast the drive
ramps and how promptly a TTL expires are timed in simulated time by the simulator's and the
control loop's own tests.)"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable
from datetime import datetime
from itertools import pairwise
from pathlib import Path
from zoneinfo import ZoneInfo

import pytest
from django.conf import settings
from playwright.sync_api import Page, Request, Route, expect

from basestation.client import AgentClient
from core.audit.models import AuditEvent
from portal.runs.services.robot import HOLD_TTL_S
from tests.browser.conftest import login
from tests.factories import MobileResourceFactory, UserFactory

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]

VELOCITY_MPS = 0.5
# Only bounds a hang: how fast the drive ramps down is the simulated robot's physics, tested
# in simulated time (tests/basestation/sim); in wall time it stretches on a loaded machine.
STOP_DEADLINE_S = 15.0


@pytest.fixture
def stack(module_stack):
    """One system for the module: each test leaves the robot standing, as it found it."""
    return module_stack


def _velocity_mps(agent: AgentClient) -> float:
    return float(agent.status()["robot"]["velocity_mps"] or 0.0)


def _wait_velocity(
    agent: AgentClient, reached, deadline_s: float, page: Page | None = None
) -> float:
    """Poll the robot until ``reached(velocity)``; the seconds it took (fails at the deadline).
    With ``page``, it waits on the page: a route the test set up is served meanwhile."""
    start = time.monotonic()
    while True:
        velocity = _velocity_mps(agent)
        if reached(velocity):
            return time.monotonic() - start
        assert time.monotonic() - start < deadline_s, f"velocity stayed {velocity} m/s"
        if page is None:
            time.sleep(0.02)
        else:
            page.wait_for_timeout(20)


def _stops(agent: AgentClient, deadline_s: float = STOP_DEADLINE_S) -> None:
    """From now on the base station's command only falls (it ramps down to 0 at the robot's
    deceleration) and the robot, never faster than it was held at (the drive lags the
    command a little), comes to a stand."""
    start = time.monotonic()
    commanded_mps = float("inf")
    while True:
        robot = agent.status()["robot"]
        now_commanded = float(robot["commanded_velocity_mps"] or 0.0)
        velocity_mps = float(robot["velocity_mps"] or 0.0)
        assert now_commanded <= commanded_mps + 1e-6, f"command rose to {now_commanded} m/s"
        assert velocity_mps <= VELOCITY_MPS + 0.01, f"sped up to {velocity_mps} m/s"
        commanded_mps = now_commanded
        if commanded_mps == 0.0 and velocity_mps < 0.005:
            return
        assert time.monotonic() - start < deadline_s, f"still at {velocity_mps} m/s"
        time.sleep(0.02)


def _commanded_zero(agent: AgentClient, deadline_s: float) -> None:
    """Poll until the base station commands 0 (fails at the deadline)."""
    start = time.monotonic()
    while agent.status()["robot"]["commanded_velocity_mps"] != 0.0:
        assert time.monotonic() - start < deadline_s, "the base station still drives"
        time.sleep(0.02)


def _is_control(request: Request) -> bool:
    return "/robot/control/" in request.url


def _is_stop(request: Request) -> bool:
    return _is_control(request) and json.loads(request.post_data or "{}").get("velocity_mps") == 0


def _on_page_until(page: Page, done: Callable[[], bool], what: str) -> None:
    """Poll ``done()`` while waiting on the page, so that Playwright delivers the page's events
    and serves the test's routes meanwhile (fails at the deadline, saying ``what``)."""
    start = time.monotonic()
    while not done():
        assert time.monotonic() - start < STOP_DEADLINE_S, what
        page.wait_for_timeout(20)


class Controls:
    """The page's drive commands: those sent, those not yet answered, and the last answered."""

    def __init__(self, page: Page) -> None:
        self.page = page
        self.sent: list[Request] = []
        self.waiting: list[Request] = []
        self.last_answered: Request | None = None
        page.on("request", self._sent)
        page.on("requestfinished", self._answered)
        page.on("requestfailed", self._answered)

    def _sent(self, request: Request) -> None:
        if _is_control(request):
            self.sent.append(request)
            self.waiting.append(request)

    def _answered(self, request: Request) -> None:
        if request in self.waiting:
            self.waiting.remove(request)
            self.last_answered = request

    @property
    def answered(self) -> int:
        return len(self.sent) - len(self.waiting)

    def settled_on_a_stop(self) -> None:
        """Poll until no command is on its way (fails at the deadline), and check the last
        one answered was a stop."""
        _on_page_until(self.page, lambda: not self.waiting, "a drive command is still unanswered")
        assert self.last_answered is not None, "no command was answered"
        assert _is_stop(self.last_answered), self.last_answered.post_data


def _release(page: Page, controls: Controls, let_go: Callable[[], None]) -> None:
    """``let_go()`` (a button or key released), wait until its stop has been answered and no
    command is on its way, and check the last one the base station was given is a stop (a
    repeat that was still on its way when the hold ended is followed by another stop)."""
    with page.expect_response(lambda r: _is_stop(r.request), timeout=15_000) as answered:
        let_go()
    assert answered.value.ok, answered.value.status
    controls.settled_on_a_stop()


def _console(browser, stack, username: str, width: int = 390) -> Page:
    page = browser.new_context(viewport={"width": width, "height": 844}).new_page()
    login(page, stack.web, username, "correct horse battery")
    page.goto(f"{stack.web}/robot/mobile-1/")
    expect(page.locator("#st-link")).to_contain_text("up", timeout=15_000)
    page.locator("#held-velocity").fill(str(VELOCITY_MPS))
    page.locator("#held-reason").fill("moving it to the north corner")
    return page


def test_the_robot_drives_only_while_held_and_ramps_to_a_stand_when_let_go(browser, stack):
    MobileResourceFactory(agent_url=stack.agent_url)
    UserFactory(username="root", is_staff=True, is_superuser=True)
    page = _console(browser, stack, "root")
    controls = Controls(page)
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))

    hold = page.get_by_role("button", name="Hold: clockwise ▶")
    # The e-stop stays in view wherever the page is scrolled to.
    hold.scroll_into_view_if_needed()
    expect(page.get_by_test_id("estop")).to_be_in_viewport()
    hold.hover()
    page.mouse.down()
    _wait_velocity(stack.agent, lambda v: v >= VELOCITY_MPS - 0.05, deadline_s=10)
    expect(page.locator("#hold-state")).to_have_attribute("data-state", "driving")
    expect(hold).to_have_attribute("aria-pressed", "true")
    # Held until repeated (the drive can reach its speed before the first repeat is answered).
    _on_page_until(page, lambda: controls.answered >= 2, "the hold was not repeated")
    _release(page, controls, page.mouse.up)
    _stops(stack.agent)
    expect(page.locator("#hold-state")).to_have_text("Stopped.")
    # Held long enough to be repeated, yet audited once, and its stop once.
    assert len(controls.sent) >= 3
    audit_rows = list(
        AuditEvent.objects.filter(action="robot.control")
        .order_by("pk")
        .values_list("data", flat=True)
    )
    # A hold and its stop, once each; again only if a repeat on its way when the button was let
    # go reached the base station after the stop (the page then stops it once more).
    # (A repeat's check of the last command may also interleave with the stop's, on two of
    # the web server's threads: the page's second stop is then audited too, after the first.)
    audited = [(c["velocity_mps"], c.get("hold")) for c in audit_rows]
    drive, stop = (VELOCITY_MPS, True), (0.0, True)
    assert audited[0] == drive, audited
    assert audited[-1] == stop, audited
    assert set(audited) <= {drive, stop}, audited
    assert not any(a == b == drive for a, b in pairwise(audited)), audited
    assert 1 <= audited.count(stop) <= sum(1 for request in controls.sent if _is_stop(request))

    # The keyboard: → drives clockwise while held, its release stops.
    page.locator("body").click(position={"x": 5, "y": 5})
    page.keyboard.down("ArrowRight")
    _wait_velocity(stack.agent, lambda v: v >= 0.2, deadline_s=10)
    _release(page, controls, lambda: page.keyboard.up("ArrowRight"))
    _stops(stack.agent)

    # The day's log names the admin's manual session, on screen and as a download.
    page.get_by_role("button", name="Show").click()
    expect(page.locator("#log-rows tr").first.locator("td").first).to_have_text("root")
    # Its times on the testbed's wall clock, to the second (the agent's are UTC, to the µs).
    start = page.locator("#log-rows tr").first.locator("td").nth(2)
    expect(start).to_have_text(re.compile(r"^\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2}$"))
    shown = datetime.strptime(start.inner_text(), "%Y-%m-%d %H:%M:%S")
    utc = datetime.fromisoformat(start.get_attribute("title") or "")
    zone = ZoneInfo(settings.TIME_ZONE)
    assert shown == utc.astimezone(zone).replace(tzinfo=None, microsecond=0)
    with page.expect_download() as download_info:
        page.get_by_role("button", name="Download CSV").click()
    lines = Path(download_info.value.path()).read_text().splitlines()
    assert lines[0] == "user,title,start,end,kind,run_id,state"
    assert lines[1].startswith("root,")
    assert not errors, errors
    page.context.close()


# In the page: each reading the readout beside the buttons shows, and when a hold began and
# ended, on the page's clock (performance.now(), ms).
RECORD_READINGS = """() => {
  window.readings = [];
  window.holds = [];
  const live = document.getElementById("hold-live");
  const velocity = () => Number(live.dataset.velocityMps || 0);
  new MutationObserver(() => window.readings.push([performance.now(), velocity()]))
    .observe(live, { attributes: true, attributeFilter: ["data-readings"] });
  const at = (what) => () => window.holds.push([what, performance.now()]);
  document.addEventListener("pointerdown", at("down"), true);
  document.addEventListener("pointerup", at("up"), true);
}"""

READINGS_SINCE_DOWN = """() => {
  const down = window.holds.find(([what]) => what === "down")[1];
  return window.readings.filter(([t]) => t >= down).length;
}"""


def test_the_readout_beside_the_buttons_follows_the_robot_while_held_and_after(browser, stack):
    """Velocity, position, link and stop beside the buttons, from every drive command's answer
    while held (five a second) and from the robot's status while it ramps down after; the
    page's own timings of the first changed reading are reported (the bound only catches a
    hang: how soon depends on the machine's load, and is measured there)."""
    MobileResourceFactory(agent_url=stack.agent_url)
    UserFactory(username="root", is_staff=True, is_superuser=True)
    page = _console(browser, stack, "root", width=1280)
    controls = Controls(page)
    hold = page.get_by_role("button", name="Hold: clockwise ▶")
    hold.scroll_into_view_if_needed()
    # Read where the buttons are: the readout and both buttons in view at once.
    expect(page.locator("#hold-live")).to_be_in_viewport()
    expect(page.locator("#hl-link")).to_contain_text("up")
    expect(page.locator("#hl-estop")).to_have_text("released")
    page.evaluate(RECORD_READINGS)

    hold.hover()
    page.mouse.down()
    _wait_velocity(stack.agent, lambda v: v >= VELOCITY_MPS - 0.05, deadline_s=10, page=page)
    expect(page.locator("#hl-velocity")).to_have_text(re.compile(r"^0\.[1-9]\d m/s cw$"))
    # Held until repeats were answered too (the drive can reach its speed after two answers),
    # and each answer was shown before letting go (the page reads it after Playwright sees it).
    _on_page_until(page, lambda: controls.answered >= 3, "fewer than 3 commands answered")
    answered_while_held = controls.answered
    _on_page_until(
        page,
        lambda: page.evaluate(READINGS_SINCE_DOWN) >= answered_while_held,
        "an answered command was not shown beside the buttons",
    )
    _release(page, controls, page.mouse.up)
    _stops(stack.agent)
    expect(page.locator("#hl-velocity")).to_have_text("0.00 m/s", timeout=STOP_DEADLINE_S * 1000)

    readings: list[list[float]] = page.evaluate("window.readings")
    holds = dict(page.evaluate("window.holds"))
    during = [v for t, v in readings if holds["down"] <= t <= holds["up"]]
    after = [(t, v) for t, v in readings if t > holds["up"]]
    # Every answered command of the hold was shown (and the stream's copies of them).
    assert len(during) >= answered_while_held >= 3, (during, answered_while_held)
    moving_ms = next(t for t, v in readings if t >= holds["down"] and v > 0) - holds["down"]
    slowing_ms = next(t for t, v in after if v < max(during)) - holds["up"]
    assert 0 < moving_ms < STOP_DEADLINE_S * 1000
    assert 0 < slowing_ms < STOP_DEADLINE_S * 1000
    held_s = (holds["up"] - holds["down"]) / 1000
    print(
        f"readout: moving {moving_ms:.0f} ms after the press, slowing {slowing_ms:.0f} ms "
        f"after letting go, {len(during) / held_s:.1f} readings/s while held"
    )
    assert after[-1][1] == 0.0
    page.context.close()


def test_a_repeat_still_on_its_way_when_let_go_is_followed_by_another_stop(browser, stack):
    """A slow repeat can reach the base station after the stop sent on letting go, and would
    drive the robot again until its TTL: the page stops it once more when it is answered."""
    MobileResourceFactory(agent_url=stack.agent_url)
    UserFactory(username="root", is_staff=True, is_superuser=True)
    page = _console(browser, stack, "root")
    controls = Controls(page)
    armed = False
    held_back: list[Route] = []

    def hold_back_one_repeat(route: Route) -> None:
        driving = json.loads(route.request.post_data or "{}").get("velocity_mps")
        if armed and driving and not held_back:
            held_back.append(route)  # answered when the test says
        else:
            route.continue_()

    page.route("**/robot/control/", hold_back_one_repeat)
    page.get_by_role("button", name="Hold: clockwise ▶").hover()
    page.mouse.down()
    _wait_velocity(stack.agent, lambda v: v >= 0.2, deadline_s=10, page=page)
    armed = True
    _on_page_until(page, lambda: bool(held_back), "the page repeated nothing")
    # Let go while that repeat is on its way: the stop goes at once...
    with page.expect_response(lambda r: _is_stop(r.request), timeout=15_000) as answered:
        page.mouse.up()
    assert answered.value.ok
    # ...then the repeat arrives, late, and once it is answered the stop goes again.
    with page.expect_request(_is_stop, timeout=15_000):
        held_back[0].continue_()
    controls.settled_on_a_stop()
    _stops(stack.agent)
    expect(page.locator("#hold-state")).to_have_text("Stopped.")
    page.context.close()


def test_a_page_closed_mid_hold_with_its_stop_lost_is_stopped_by_the_ttl(browser, stack):
    MobileResourceFactory(agent_url=stack.agent_url)
    UserFactory(username="root", is_staff=True, is_superuser=True)
    page = _console(browser, stack, "root")
    page.get_by_role("button", name="Hold: counter-clockwise").hover()
    page.mouse.down()
    _wait_velocity(stack.agent, lambda v: v >= 0.2, deadline_s=10)
    # The network goes with the page: not even the stop sent on leaving reaches the portal.
    page.route("**/robot/control/", lambda route: route.abort())
    page.context.close()
    # The last command expires on the base station, and the robot ramps down from at most
    # the held velocity.
    _commanded_zero(stack.agent, deadline_s=HOLD_TTL_S + STOP_DEADLINE_S)
    _stops(stack.agent)
