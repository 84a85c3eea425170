"""The experiment builder in Chromium: limits checked while typing, the velocity profile's
distance, laps and end position, reordering, cloning, and the files the CLI reads."""

from __future__ import annotations

import json
from datetime import timedelta

import pytest
import yaml
from django.utils import timezone
from playwright.sync_api import Page, expect

from portal.experiments.models import Experiment
from portal.runs.services.reservations import reservation_create
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import FixedResourceFactory, MobileResourceFactory, UserFactory
from tests.runs.driving import completed_run, ramped_travel

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]
PASSWORD = "correct horse battery"
ACCEL_MPS2 = 1.0
RAIL_M = 5.0


def _fill(page: Page, segments: list[tuple[float, str, float]]) -> None:
    rows = page.locator("#segments tbody tr")
    while rows.count() < len(segments):
        page.get_by_role("button", name="Add segment").click()
    for i, (mps, direction, duration_s) in enumerate(segments):
        row = rows.nth(i)
        row.get_by_label("velocity in m/s").fill(str(mps))
        row.get_by_label("direction").select_option(direction)
        row.get_by_label("duration in s").fill(str(duration_s))


def _segments_shown(page: Page) -> list[tuple[str, str, str]]:
    rows = page.locator("#segments tbody tr")
    return [
        (
            rows.nth(i).get_by_label("velocity in m/s").input_value(),
            rows.nth(i).get_by_label("direction").input_value(),
            rows.nth(i).get_by_label("duration in s").input_value(),
        )
        for i in range(rows.count())
    ]


@pytest.fixture
def page(browser, live_server):
    UserFactory(username="kim")
    MobileResourceFactory(max_velocity_mps=1.5, max_accel_mps2=ACCEL_MPS2)
    context = browser.new_context(viewport={"width": 1280, "height": 1000})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    login(page, live_server.url, "kim", PASSWORD)
    page.goto(f"{live_server.url}/experiments/new/")
    yield page
    assert not errors, errors
    context.close()


def test_the_builder_checks_limits_and_previews_distance_laps_and_end(page):
    expect(page.get_by_test_id("builder-limits")).to_have_text(
        "mobile-1: at most 1.50 m/s, ramps at 1.00 m/s²."
    )
    page.get_by_label("Title").fill("there and back")
    program = [(1.0, "cw", 10.0), (0.5, "ccw", 6.0)]
    _fill(page, program)
    page.get_by_label("rail length in m").fill(str(RAIL_M))
    distance_m, displacement_m = ramped_travel(program, ACCEL_MPS2)
    expect(page.get_by_test_id("builder-duration")).to_have_text("16.0 s")
    expect(page.get_by_test_id("builder-distance")).to_have_text(f"{distance_m:.2f} m")
    expect(page.get_by_test_id("builder-laps")).to_have_text(f"{distance_m / RAIL_M:.2f}")
    expect(page.get_by_test_id("builder-end")).to_have_text(
        f"{displacement_m % RAIL_M:.2f} m clockwise from the start"
    )
    expect(page.get_by_test_id("builder-problems")).to_have_text("")
    # The reversal's ramp is shown beside its segment.
    expect(page.locator("#segments tbody tr").nth(1).locator(".segment-note")).to_have_text(
        "Ramps for 1.50 s."
    )
    page.screenshot(path=str(SCREENSHOTS / "experiment-builder.png"), full_page=True)

    # Over the robot's limit, and too short to reach its velocity: said while typing.
    rows = page.locator("#segments tbody tr")
    # A new segment: nothing is called wrong while it is typed; once its field is left, the
    # error stands under that field (and in the list), and the preview says it leaves it out.
    page.get_by_role("button", name="Add segment").click()
    velocity = rows.nth(2).get_by_label("velocity in m/s")
    velocity.fill("2")
    problems = page.get_by_test_id("builder-problems")
    expect(page.get_by_test_id("builder-duration")).to_have_text(
        "16.0 s (without segment 2: not complete or not valid)"
    )
    expect(velocity).not_to_have_attribute("aria-invalid", "true")
    expect(problems).to_have_text("")
    velocity.press("Tab")
    expect(problems).to_have_text("Segment 2: 2.00 m/s is above mobile-1's 1.50 m/s.")
    expect(velocity).to_have_attribute("aria-invalid", "true")
    expect(rows.nth(2).locator(".field-error[data-for=velocity_mps]")).to_have_text(
        "2.00 m/s is above mobile-1's 1.50 m/s."
    )
    # Its duration, not yet typed, is not called wrong.
    expect(rows.nth(2).locator(".field-error[data-for=duration_s]")).to_have_text("")
    expect(page.get_by_test_id("builder-distance")).to_have_text("—")
    rows.nth(2).get_by_role("button", name="remove segment").click()
    expect(problems).to_have_text("")
    rows.nth(0).get_by_label("velocity in m/s").fill("1.2")
    rows.nth(0).get_by_label("duration in s").fill("0.5")
    expect(problems).to_contain_text(
        "Segment 0: too short to reach 1.20 m/s (needs 1.20 s of ramp)."
    )
    expect(rows.nth(0).locator(".segment-note")).to_contain_text("Reaches only 0.50 m/s")


def test_segments_reorder_by_keyboard_and_drag_clone_and_round_trip_as_files(
    page, tmp_path, live_server
):
    page.get_by_label("Title").fill("three steps")
    _fill(page, [(0.2, "cw", 1.0), (0.4, "ccw", 2.0), (0.6, "cw", 3.0)])
    rows = page.locator("#segments tbody tr")
    rows.nth(2).get_by_label("duration in s").press("Alt+ArrowUp")
    assert _segments_shown(page)[:3] == [
        ("0.2", "cw", "1.0"),
        ("0.6", "cw", "3.0"),
        ("0.4", "ccw", "2.0"),
    ]
    rows.nth(0).get_by_role("button", name="move segment down").click()
    assert _segments_shown(page)[:3] == [
        ("0.6", "cw", "3.0"),
        ("0.2", "cw", "1.0"),
        ("0.4", "ccw", "2.0"),
    ]
    rows.nth(2).locator(".index").drag_to(rows.nth(0).locator(".index"))
    expect(rows.nth(0).get_by_label("velocity in m/s")).to_have_value("0.4")
    rows.nth(1).get_by_role("button", name="copy segment").click()
    assert _segments_shown(page) == [
        ("0.4", "ccw", "2.0"),
        ("0.6", "cw", "3.0"),
        ("0.6", "cw", "3.0"),
        ("0.2", "cw", "1.0"),
    ]
    expect(page.locator("#segments tbody tr .index")).to_have_text(["0", "1", "2", "3"])

    with page.expect_download() as exported:
        page.get_by_role("button", name="Download JSON").click()
    saved = json.loads(exported.value.path().read_text())
    assert saved == {
        "title": "three steps",
        "segments": [
            {"velocity_mps": 0.4, "direction": "ccw", "duration_s": 2},
            {"velocity_mps": 0.6, "direction": "cw", "duration_s": 3},
            {"velocity_mps": 0.6, "direction": "cw", "duration_s": 3},
            {"velocity_mps": 0.2, "direction": "cw", "duration_s": 1},
        ],
    }
    with page.expect_download() as exported_yaml:
        page.get_by_role("button", name="Download YAML").click()
    assert yaml.safe_load(exported_yaml.value.path().read_text()) == saved

    # A file the CLI reads comes back in; a broken one changes nothing.
    good = tmp_path / "loop.yaml"
    good.write_text(
        "title: loop\nsegments:\n  - {velocity_mps: 0.5, direction: cw, duration_s: 60}\n"
        "  - {velocity_mps: 0.8, direction: ccw, duration_s: 30}\n"
    )
    bad = tmp_path / "bad.json"
    bad.write_text('{"title": "x", "segments": [{"velocity_mps": -1, "direction": "cw"}]}')
    page.locator("#builder-import").set_input_files(str(bad))
    expect(page.locator("#builder-import-status")).to_contain_text(
        "bad.json was not imported: segments.0.velocity_mps"
    )
    assert len(_segments_shown(page)) == 4
    page.locator("#builder-import").set_input_files(str(good))
    expect(page.locator("#builder-import-status")).to_contain_text("Imported loop.yaml: 2 segments")
    assert _segments_shown(page) == [("0.5", "cw", "60"), ("0.8", "ccw", "30")]
    expect(page.get_by_label("Title")).to_have_value("loop")
    page.get_by_role("button", name="Save experiment").click()
    expect(page.get_by_text("Experiment “loop” saved.")).to_be_visible()
    saved_experiment = Experiment.objects.get(title="loop")
    assert [s["velocity_mps"] for s in saved_experiment.segments] == [0.5, 0.8]


@pytest.mark.parametrize("width", [1280, 375])
def test_no_control_is_clipped_and_the_rail_is_shown_to_the_centimetre(browser, live_server, width):
    """Every field and button of a segment lies inside its table's box (at a laptop's width
    beside the preview, on a phone as a card), the direction reads whole, and the robot's
    measured rail length is shown rounded, not with the digits no one typed. On a phone the
    home page's bookings are cards too: every value on screen."""
    user = UserFactory(username="lea")
    # The rail as the robot last measured it, on its latest run.
    completed_run(
        user, MobileResourceFactory(), [(0.5, "cw", 1.0)], rail_length_m=120.0106556346223
    )
    node = FixedResourceFactory(name="node-01")
    start = timezone.now() + timedelta(days=1)
    reservation_create(owner=user, resource=node, start_at=start, end_at=start + timedelta(hours=1))
    context = browser.new_context(viewport={"width": width, "height": 900})
    page = context.new_page()
    login(page, live_server.url, "lea", PASSWORD)
    page.goto(f"{live_server.url}/experiments/new/")
    expect(page.locator("#builder-rail")).to_have_value("120.01")
    # The box the table scrolls in: what lies past its edge is cut off.
    table = page.locator("#segments").locator("xpath=..").bounding_box()
    assert table
    controls = page.locator("#segments tbody tr").first.locator("input, select, button")
    for i in range(controls.count()):
        box = controls.nth(i).bounding_box()
        assert box
        assert table["x"] - 1 <= box["x"]
        assert box["x"] + box["width"] <= table["x"] + table["width"] + 1, i
        assert box["x"] + box["width"] <= width
    direction = page.locator("#segments tbody tr").first.get_by_label("direction")
    # The chosen direction's text fits inside the select, beside its arrow.
    fits = """(s) => {
        const style = getComputedStyle(s);
        const context = document.createElement("canvas").getContext("2d");
        context.font = style.font;
        const text = context.measureText(s.options[s.selectedIndex].text).width;
        return text + parseFloat(style.paddingLeft) + parseFloat(style.paddingRight)
            <= s.clientWidth + 1;
    }"""
    assert direction.evaluate(fits)

    page.goto(f"{live_server.url}/")
    for cell in ("node-01", "Cancel"):
        box = page.locator("#upcoming").get_by_text(cell).first.bounding_box()
        assert box
        assert box["x"] + box["width"] <= width
    assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth + 1")
    context.close()
