"""The resource timeline in Chromium: every robot and fixed node a row; a drag across rows
books them together, with the live check answering while dragging."""

from __future__ import annotations

import re
from datetime import date, datetime, timedelta
from zoneinfo import ZoneInfo

import pytest
import requests
from django.conf import settings
from django.utils import timezone
from playwright.sync_api import Page, expect

from bookings.models import Blackout, Reservation, SchedulerLease
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import (
    ExperimentFactory,
    FixedResourceFactory,
    MobileResourceFactory,
    UserFactory,
)

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]
PASSWORD = "correct horse battery"


def _tomorrow() -> date:
    """A day whose every slot is in the future, whenever the test runs."""
    return (timezone.now().astimezone(ZoneInfo(settings.TIME_ZONE)) + timedelta(days=1)).date()


def _open_day(page: Page, web: str, day: date, *, streamed: bool = True) -> None:
    """Open the timeline and go to ``day``, counting from the day the page opened on (its own
    clock's today): if midnight passed since the test chose ``day``, that is one click less."""
    page.goto(f"{web}/calendar/timeline/")
    expect(page.locator("#timeline[data-loading=false]")).to_be_attached()
    if streamed:
        # The stream is open: the page's read on connecting is asked, not still to come
        # mid-drag. (Django's test server serves no streams: the page polls instead.)
        expect(page.locator("#live-status")).to_have_attribute("data-state", "live")
    shown = page.locator(".ec-col-head time[datetime]").first.get_attribute("datetime")
    assert shown
    clicks = (day - date.fromisoformat(shown[:10])).days
    assert clicks in (0, 1), f"the page opened on {shown}, the test wants {day}"
    for _ in range(clicks):
        page.locator(".ec-next").first.click()
    expect(page.locator(f".ec-col-head time[datetime='{day.isoformat()}']")).to_be_visible()
    expect(page.locator("#timeline[data-loading=false]")).to_be_attached()


def _slot_x(page: Page, day: date, hour: int) -> float:
    """The left edge of ``hour``:00 on ``day`` in the timeline's header, the grid scrolled
    sideways first if that hour is out of sight. The page opens scrolled to the hour before
    now, so an earlier hour may lie under the rows' names: they stay in place over the
    scrolled grid, and Playwright's scroll_into_view_if_needed counts it as seen there."""
    box = page.locator(f".ec-slots time[datetime='{day.isoformat()}T{hour:02d}:00:00']")
    box.scroll_into_view_if_needed()
    page.evaluate(
        """(label) => {
            const cell = label.parentElement.getBoundingClientRect();
            const main = label.closest(".ec-main");
            const names = main.querySelector(".ec-row-head").getBoundingClientRect();
            const grid = main.getBoundingClientRect();
            if (cell.left < names.right || cell.right > grid.right) {
                main.scrollLeft += cell.left - names.right - 2 * cell.width;
            }
        }""",
        box.element_handle(),
    )
    bounds = box.locator("xpath=..").bounding_box()
    assert bounds
    return bounds["x"]


def _row_y(page: Page, name: str) -> float:
    bounds = _row_box(page, name)
    return bounds["y"] + bounds["height"] / 2


def _drag(page: Page, day: date, hours: tuple[int, int], rows: tuple[str, str]) -> None:
    """Press in the first row at the first hour, and bring the pointer to the last row before
    the second, still pressed."""
    x0 = _slot_x(page, day, hours[0]) + 4
    x1 = _slot_x(page, day, hours[1]) - 4
    y0, y1 = _row_y(page, rows[0]), _row_y(page, rows[1])
    page.mouse.move(x0, y0)
    page.mouse.down()
    page.mouse.move((x0 + x1) / 2, (y0 + y1) / 2, steps=6)
    # As a person watches the pointer: if the page has moved under it meanwhile (a line of
    # the live check, a re-read of the calendar, a scroll, the picked rows' labels turned
    # bold), it is brought to the last row where that row is now, just before the hour
    # (within the last five minutes: the drag snaps to five). Each correction is printed,
    # so a failure shows what moved.
    y = y1
    for attempt in range(4):
        page.mouse.move(_slot_x(page, day, hours[1]) - 2, y, steps=6)
        box = _row_box(page, rows[1])
        if box["y"] <= y < box["y"] + box["height"]:
            return
        scroll_y = page.evaluate("window.scrollY")
        print(
            f"the {rows[1]} row moved under the pointer (try {attempt}): pointer at y={y:.0f}, "
            f"row now {box['y']:.0f}–{box['y'] + box['height']:.0f}, scrollY {scroll_y}"
        )
        y = box["y"] + box["height"] / 2
    raise AssertionError(f"the {rows[1]} row kept moving under the pointer")


def _row_box(page: Page, name: str) -> dict[str, float]:
    label = page.locator(f"[data-resource='{name}']")
    bounds = page.locator(".ec-row-head", has=label).bounding_box()
    assert bounds
    return bounds


def _broker_leases(standin: str) -> list[dict]:
    answer = requests.get(
        f"{standin}/resources/leases",
        params={"status": "pending,accepted,active,past,cancelled"},
        timeout=10,
    )
    if answer.status_code == 404:
        return []
    return answer.json()["resource_response"]["resources"]


def test_a_drag_over_the_robot_and_two_nodes_books_them_in_one_lease(browser, stack_with_scheduler):
    stack = stack_with_scheduler
    user = UserFactory(username="hana")
    MobileResourceFactory(agent_url=stack.agent_url)
    for name in ("node-01", "node-02", "node-03"):
        FixedResourceFactory(name=name)
    ExperimentFactory(owner=user, title="loop test")
    context = browser.new_context(
        viewport={"width": 1280, "height": 1000}, timezone_id=settings.TIME_ZONE
    )
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    refused: list[str] = []
    page.on("console", lambda m: "Content Security Policy" in m.text and refused.append(m.text))
    login(page, stack.web, "hana", PASSWORD)
    page.get_by_role("link", name="Timeline").click()
    expect(page.get_by_test_id("timeline-zone")).to_have_text(settings.TIME_ZONE)
    day = _tomorrow()
    _open_day(page, stack.web, day)

    _drag(page, day, (10, 11), ("mobile-1", "node-02"))
    # The page took the drag across the three rows (marked at once, before the check answers)...
    expect(page.locator("#timeline .timeline-picked")).to_have_count(3)
    # ...and while the button is still down, the live check has answered for them: the robot
    # still needs its experiment, chosen in the dialog.
    check = page.get_by_test_id("timeline-check")
    expect(check).to_contain_text("mobile-1, node-01, node-02")
    expect(check).to_contain_text("Choose the experiment the robot will run.")
    page.mouse.up()

    dialog = page.locator("#timeline-dialog")
    expect(dialog).to_be_visible()
    expect(dialog.get_by_label("Start")).to_have_value(f"{day.isoformat()}T10:00")
    expect(dialog.get_by_label("End")).to_have_value(f"{day.isoformat()}T11:00")
    for name in ("mobile-1", "node-01", "node-02"):
        expect(dialog.get_by_label(name)).to_be_checked()
    expect(dialog.get_by_label("node-03")).not_to_be_checked()
    # A time the clocks skip is refused in the dialog, saying why (core/wall_clock.py's rule).
    dialog.get_by_label("Start").fill("2027-03-28T01:30")
    expect(page.locator("#timeline-feedback")).to_have_text(
        "01:30 does not exist on 28 March 2027 in Europe/Lisbon: "
        "clocks go forward from 01:00 to 02:00."
    )
    dialog.get_by_label("Start").fill(f"{day.isoformat()}T10:00")
    dialog.get_by_label("experiment").select_option(label="loop test (6 s)")
    expect(page.locator("#timeline-feedback")).to_contain_text("Free, and within your quota")
    dialog.get_by_role("button", name="Confirm booking").click()
    expect(dialog).to_be_hidden()
    expect(page.locator(".ec-event", has_text="loop test")).to_have_count(3)  # one per row

    reservation = Reservation.objects.get()
    assert sorted(i.resource.name for i in reservation.items.all()) == [
        "mobile-1",
        "node-01",
        "node-02",
    ]
    assert reservation.run.experiment.title == "loop test"
    zone = ZoneInfo(settings.TIME_ZONE)
    assert reservation.start_at == datetime(day.year, day.month, day.day, 10, tzinfo=zone)
    assert reservation.end_at == datetime(day.year, day.month, day.day, 11, tzinfo=zone)
    [lease] = [x for x in _broker_leases(stack.standin) if x["status"] in ("accepted", "active")]
    assert sorted(c["name"] for c in lease["components"]) == ["node-01", "node-02"]
    assert lease["uuid"] == reservation.lease_uuid
    expect(page.locator("#timeline-flash a")).to_have_attribute(
        "href", f"/runs/{reservation.run.pk}/"
    )
    page.screenshot(path=str(SCREENSHOTS / "timeline.png"))

    # The book page books the same way: the robot (first, and ticked for the experiment it
    # fits) with two nodes is one booking, its run, and one lease for the nodes.
    page.goto(f"{stack.web}/book/?experiment={reservation.run.experiment_id}")
    expect(page.locator("#book-resources input").first).to_have_attribute("value", "mobile-1")
    expect(page.get_by_label("mobile-1 (robot)")).to_be_checked()
    page.get_by_label("node-01").check()
    page.get_by_label("node-03").check()
    page.get_by_label("Start").fill(f"{day.isoformat()}T12:00")
    page.get_by_label("End").fill(f"{day.isoformat()}T12:30")
    page.screenshot(path=str(SCREENSHOTS / "book.png"), full_page=True)
    page.get_by_role("button", name="Book", exact=True).click()
    expect(page).to_have_url(re.compile(r"/runs/\d+/$"))
    second = Reservation.objects.exclude(pk=reservation.pk).get()
    assert page.url.endswith(f"/runs/{second.run.pk}/")
    expect(page.locator("#run-countdown")).to_contain_text("Starts at 12:00:00")
    assert sorted(i.resource.name for i in second.items.all()) == ["mobile-1", "node-01", "node-03"]
    held = [x for x in _broker_leases(stack.standin) if x["uuid"] == second.lease_uuid]
    assert [sorted(c["name"] for c in x["components"]) for x in held] == [["node-01", "node-03"]]
    assert not errors, errors
    assert not refused, refused
    context.close()


def test_the_timeline_shows_leases_maintenance_and_holds_on_their_rows(browser, live_server):
    UserFactory(username="ines")
    MobileResourceFactory(
        held_at=timezone.now() - timedelta(hours=1), hold_reason="battery below 11.0 V"
    )
    node1 = FixedResourceFactory(name="node-01")
    node2 = FixedResourceFactory(name="node-02")
    day = _tomorrow()
    zone = ZoneInfo(settings.TIME_ZONE)
    at = datetime(day.year, day.month, day.day, tzinfo=zone)
    lease = SchedulerLease.objects.create(
        uuid="lease-elsewhere",
        name="mesh survey",
        start_at=at + timedelta(hours=9),
        end_at=at + timedelta(hours=12),
        status="accepted",
        components=["node-01"],
        holds=True,
        seen_at=timezone.now(),
    )
    lease.resources.add(node1)
    blackout = Blackout.objects.create(
        start_at=at + timedelta(hours=14), end_at=at + timedelta(hours=16), reason="new antennas"
    )
    blackout.resources.add(node2)
    context = browser.new_context(
        viewport={"width": 1280, "height": 1000}, timezone_id=settings.TIME_ZONE
    )
    page = context.new_page()
    login(page, live_server.url, "ines", PASSWORD)
    _open_day(page, live_server.url, day, streamed=False)

    rows = page.locator(".ec-body .ec-grid .ec-day")
    # The rows: the robots' group, mobile-1, the fixed nodes' group, node-01, node-02.
    expect(page.locator(".ec-row-head")).to_contain_text(
        ["Robots", "mobile-1", "Fixed nodes", "node-01", "node-02"]
    )
    lease_event = page.locator(".ec-event[data-kind='lease']")
    expect(lease_event).to_contain_text("mesh survey")
    maintenance = page.locator(".ec-event[data-kind='blackout']")
    expect(maintenance).to_contain_text("new antennas")
    hold = page.locator(".ec-event[data-kind='hold']")
    expect(hold).to_contain_text("battery below 11.0 V")
    expect(page.locator("[data-resource='mobile-1']")).to_have_class(
        re.compile(r"\btimeline-held\b")
    )

    def row_of(event_box: dict) -> int:
        middle = event_box["y"] + event_box["height"] / 2
        for index in range(rows.count()):
            box = rows.nth(index).bounding_box()
            assert box
            if box["y"] <= middle < box["y"] + box["height"]:
                return index
        raise AssertionError("the event is on no row")

    for locator, row in ((lease_event, 3), (maintenance, 4), (hold, 1)):
        box = locator.bounding_box()
        assert box
        assert row_of(box) == row

    # Dragging into the maintenance window says so before anything is booked.
    rows_before = _row_box(page, "node-02")
    _drag(page, day, (14, 15), ("node-01", "node-02"))
    check = page.get_by_test_id("timeline-check")
    expect(check).to_contain_text("node-01, node-02")
    expect(check).to_contain_text("new antennas")
    expect(check).to_have_attribute("data-fits", "false")
    # The answer runs over two lines at this width, and the rows under the pointer stayed
    # where they were (it once pushed them down a line, and back up when it was shorter).
    line_px = float(check.evaluate("e => parseFloat(getComputedStyle(e).lineHeight)"))
    assert (check.bounding_box() or {"height": 0})["height"] > 1.5 * line_px
    assert _row_box(page, "node-02")["y"] == rows_before["y"]
    page.mouse.up()
    expect(page.locator("#timeline-dialog")).to_be_visible()
    assert not Reservation.objects.exists()
    context.close()


def test_the_timeline_fits_a_phone(browser, live_server):
    UserFactory(username="joao")
    MobileResourceFactory()
    FixedResourceFactory(name="node-01")
    context = browser.new_context(
        viewport={"width": 375, "height": 800}, timezone_id=settings.TIME_ZONE
    )
    page = context.new_page()
    login(page, live_server.url, "joao", PASSWORD)
    page.goto(f"{live_server.url}/calendar/timeline/")
    expect(page.locator("#timeline[data-loading=false]")).to_be_attached()
    expect(page.locator("[data-resource='node-01']")).to_be_visible()
    # The timeline scrolls inside its box; the page itself does not scroll sideways.
    assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth + 1")
    page.screenshot(path=str(SCREENSHOTS / "timeline-narrow.png"), full_page=True)
    context.close()


def test_a_check_without_any_answer_says_so(browser, live_server):
    """The connection drops under the live check: the line says so (the pages' API helper
    answers for a request that got no answer), and nothing on the page is left uncaught."""
    UserFactory(username="jon")
    for name in ("node-01", "node-02"):
        FixedResourceFactory(name=name)
    context = browser.new_context(
        viewport={"width": 1280, "height": 1000}, timezone_id=settings.TIME_ZONE
    )
    page = context.new_page()
    login(page, live_server.url, "jon", PASSWORD)
    day = _tomorrow()
    _open_day(page, live_server.url, day, streamed=False)
    page.route("**/api/v1/reservations/check/", lambda route: route.abort("connectionreset"))

    _drag(page, day, (9, 10), ("node-01", "node-02"))
    check = page.get_by_test_id("timeline-check")
    expect(check).to_contain_text("node-01, node-02")
    expect(check).to_contain_text("The server did not answer clearly; try again.")
    expect(check).to_have_attribute("data-fits", "false")
    page.mouse.up()
    assert not page.page_errors()
    context.close()


def _x_at(page: Page, day: date, hour: int, minute: int) -> float:
    """Where ``hour``:``minute`` on ``day`` lies across the timeline."""
    left = _slot_x(page, day, hour)
    width = _slot_x(page, day, hour + 1) - left
    return _slot_x(page, day, hour) + width * minute / 60


def _press_across(page: Page, row: str, day: date, start: tuple[int, int], end: tuple[int, int]):
    """Press in ``row`` at ``start`` (hour, minute) and release at ``end``. Where each lies is
    read just before the pointer goes there, and again until the row is under it: the page
    moves while it settles, and the pressed row's label turns bold (the grid moves with it)."""
    page.mouse.move(_x_at(page, day, *start) + 1, _row_y(page, row))
    page.mouse.down()
    for _ in range(4):
        page.mouse.move(_x_at(page, day, *end), _row_y(page, row), steps=8)
        box = _row_box(page, row)
        if page.locator("#timeline .timeline-picked").count() == 1 and (
            box["y"] <= _row_y(page, row) < box["y"] + box["height"]
        ):
            break
    # Once more where the end is now, the label bold: the drag's end is read from this move.
    page.mouse.move(_x_at(page, day, *end), _row_y(page, row), steps=2)
    page.mouse.up()


def test_the_timeline_opens_on_now_and_a_drag_snaps_to_five_minutes_from_now_on(
    browser, live_server
):
    """At 04:07 the timeline shows 04:00 (not 08:00 and later), each hour's label on its
    gridline and a "Today" button; a drag snaps to TIMELINE_SNAP_MIN (5) minutes, and one
    that starts in the past is offered from the next five minutes after now, saying so."""
    UserFactory(username="kai")
    FixedResourceFactory(name="node-01")
    # A day ahead that is no Sunday: the clocks change on Sundays, and this test is about
    # an ordinary day's hours.
    day = _tomorrow()
    if day.weekday() == 6:
        day += timedelta(days=1)
    zone = ZoneInfo(settings.TIME_ZONE)
    context = browser.new_context(
        viewport={"width": 1280, "height": 1000}, timezone_id=settings.TIME_ZONE
    )
    page = context.new_page()
    page.clock.install(time=datetime(day.year, day.month, day.day, 4, 7, tzinfo=zone))
    login(page, live_server.url, "kai", PASSWORD)
    _open_day(page, live_server.url, day, streamed=False)

    expect(page.locator(".ec-today").first).to_have_text("Today")
    label = page.locator(f".ec-slots time[datetime='{day.isoformat()}T04:00:00']")
    expect(label).to_be_in_viewport()
    # Scrolled so that the hour before now is at the grid's left edge (not 08:00 and on).
    row_head = _row_box(page, "node-01")
    hour_width = _slot_x(page, day, 5) - _slot_x(page, day, 4)
    assert 0 < _slot_x(page, day, 4) - (row_head["x"] + row_head["width"]) <= hour_width * 1.5
    text_box, cell_box = label.bounding_box(), label.locator("xpath=..").bounding_box()
    assert text_box
    assert cell_box
    assert text_box["x"] - cell_box["x"] < 8, "the hour's label starts at its gridline"

    # 03:00 to 04:27: the start is past, so the booking is offered from 04:10 to 04:30.
    _press_across(page, "node-01", day, (3, 0), (4, 27))
    dialog = page.locator("#timeline-dialog")
    expect(dialog.get_by_label("Start")).to_have_value(f"{day.isoformat()}T04:10")
    expect(dialog.get_by_label("End")).to_have_value(f"{day.isoformat()}T04:30")
    expect(page.locator("#timeline-feedback")).to_contain_text(
        "The start was in the past: moved to 04:10."
    )
    expect(page.locator("#timeline-feedback")).to_contain_text("Free, and within your quota")
    page.locator("#timeline-close").click()

    # 10:00 to 10:17 snaps to 10:00 to 10:20, in the future: offered as dragged.
    _press_across(page, "node-01", day, (10, 0), (10, 17))
    expect(dialog.get_by_label("Start")).to_have_value(f"{day.isoformat()}T10:00")
    expect(dialog.get_by_label("End")).to_have_value(f"{day.isoformat()}T10:20")
    expect(page.locator("#timeline-feedback")).not_to_contain_text("moved")
    dialog.get_by_role("button", name="Confirm booking").click()
    expect(dialog).to_be_hidden()
    booked = Reservation.objects.get()
    assert booked.start_at == datetime(day.year, day.month, day.day, 10, tzinfo=zone)
    assert booked.end_at == datetime(day.year, day.month, day.day, 10, 20, tzinfo=zone)
    assert not page.page_errors()
    context.close()
