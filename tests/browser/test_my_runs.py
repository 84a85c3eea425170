"""My runs in Chromium: filter the list, download the chosen runs as one zip, compare them."""

from __future__ import annotations

import json
import zipfile
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from playwright.sync_api import expect

from portal.runs.states import RunState
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import MobileResourceFactory, UserFactory
from tests.runs.history import past_run

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]

START = datetime(2026, 3, 2, 10, 0, tzinfo=UTC)


@pytest.fixture
def gil_runs():
    gil = UserFactory(username="gil")
    one, two = MobileResourceFactory(), MobileResourceFactory(name="mobile-2")
    return {
        "north": past_run(gil, one, started_at=START, title="north corner"),
        "south": past_run(
            gil,
            one,
            started_at=START + timedelta(days=1),
            title="south corner",
            program=[(1.0, "cw", 2.0), (0.5, "ccw", 2.0)],
        ),
        "failed": past_run(
            gil, two, started_at=START + timedelta(days=2), title="west", state=RunState.FAILED
        ),
        "old": past_run(gil, one, started_at=START - timedelta(days=30), title="north again"),
    }


@pytest.mark.parametrize("width", [375, 1280])
def test_filter_the_list_then_download_and_compare_the_chosen_runs(
    browser, live_server, gil_runs, width
):
    context = browser.new_context(viewport={"width": width, "height": 900})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    # Nothing the pages do is refused by the Content Security Policy.
    page.on(
        "console",
        lambda m: "Content Security Policy" in m.text and errors.append(f"{page.url}: {m.text}"),
    )
    page.on(
        "response",
        lambda r: (
            r.status >= 400
            and not r.url.endswith("/favicon.ico")
            and errors.append(f"{r.status} {r.url}")
        ),
    )
    login(page, live_server.url, "gil", "correct horse battery")
    page.get_by_role("link", name="My runs").click()
    rows = page.locator("#runs tbody tr")
    expect(rows).to_have_count(4)

    filters = page.get_by_role("form", name="Filter runs")
    filters.get_by_label("Robot").select_option("mobile-2")
    filters.get_by_role("button", name="Show runs").click()
    expect(rows).to_have_count(1)
    expect(rows.first).to_contain_text("west")
    expect(rows.first.locator(".run-state")).to_have_attribute("data-state", "failed")
    page.get_by_role("button", name="Clear filters").click()
    expect(rows).to_have_count(4)

    filters.get_by_label("Search").fill("corner")
    filters.get_by_label("State").select_option("completed")
    filters.get_by_label("Started from").fill("2026-03-01")
    filters.get_by_label("Started until").fill("2026-03-31")
    filters.get_by_role("button", name="Show runs").click()
    expect(rows).to_have_count(2)
    expect(filters.get_by_label("Search")).to_have_value("corner")

    download = page.get_by_role("button", name="Download chosen (zip)")
    compare = page.get_by_role("button", name="Compare chosen")
    expect(download).to_be_disabled()
    north, south = gil_runs["north"], gil_runs["south"]
    page.get_by_label(f"Choose run {north.pk}").check()
    expect(download).to_be_enabled()
    expect(compare).to_be_disabled()
    page.get_by_label("Choose every run on this page").check()
    expect(page.get_by_role("status").filter(has_text="2 runs chosen.")).to_be_visible()
    assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth + 1")
    page.screenshot(path=str(SCREENSHOTS / f"my-runs-{width}.png"), full_page=True)

    with page.expect_download() as download_info:
        download.click()
    with zipfile.ZipFile(Path(download_info.value.path())) as archive:
        manifest = json.loads(archive.read("manifest.json"))
        assert sorted(entry["run"] for entry in manifest["runs"]) == sorted([north.pk, south.pk])
        for entry in manifest["runs"]:
            csv_lines = archive.read(entry["folder"] + "samples.csv").decode().splitlines()
            assert csv_lines[0].startswith("seq,t,segment")
            assert len(csv_lines) == entry["samples"] + 1
            descriptor = json.loads(archive.read(entry["folder"] + "datapackage.json"))
            assert descriptor["amazing"]["run"]["id"] == entry["run"]

    compare.click()
    expect(page.get_by_role("heading", name="Compare runs")).to_be_visible()
    for chart in ("compare-velocity", "compare-position"):
        page.wait_for_function(
            f"() => typeof Chart !== 'undefined' && Chart.getChart('{chart}') !== undefined"
        )
        lengths = page.evaluate(
            f"Chart.getChart('{chart}').data.datasets.map((d) => d.data.length)"
        )
        assert len(lengths) == 2, chart
        assert all(n >= 60 for n in lengths), (chart, lengths)
    # Both runs start at 0 s and 0 m, whatever their start time and place.
    firsts = page.evaluate(
        "Chart.getChart('compare-position').data.datasets.map((d) => [d.data[0].x, d.data[0].y])"
    )
    assert firsts == [[0, 0], [0, 0]]
    stats = page.locator("#compare-stats")
    expect(stats.locator("thead th[data-run]")).to_have_count(2)
    means = stats.locator('tr[data-segment="0"][data-metric="commanded"] td')
    # In the list's order, newest first: south (1 m/s), then north (0.5 m/s).
    expect(stats.locator("thead th[data-run]")).to_have_text([f"run {south.pk}", f"run {north.pk}"])
    expect(means).to_have_text(["1.00", "0.50"])
    assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth + 1")
    page.screenshot(path=str(SCREENSHOTS / f"compare-runs-{width}.png"), full_page=True)
    assert not errors, errors
    context.close()
