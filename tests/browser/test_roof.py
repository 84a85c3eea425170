"""The roof, live, in Chromium against the real stack: the rail of the agent's own rail file
(its grid cells and fixed nodes) on the run page and the robot console, and the robot moving
along it while a run drives the simulated robot.

Measurements pushed live, end to end: while the run goes on, ``python -m
basestation.sim.rssi`` (the synthetic signal strength of a fixed node of the rail's file, a
log-distance path loss with seeded shadowing) follows its samples through the API and sends a
reading for each; the open run page shows the series and colours the roof's cells without a
reload. The per-cell means the portal computes must be within four standard errors of the
model's own values: those are computed here from the model and the samples' places, not with
the portal's code."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import pytest
import requests
from django.conf import settings
from playwright.sync_api import Page, expect

from basestation.sim.rssi import PathLoss, distance_m, node_place
from basestation.telemetry.rail import DEFAULT_RAIL_PATH, Rail
from bench.stack import REPO
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import MobileResourceFactory, UserFactory
from tests.integration.experimenter import Experimenter, all_samples
from tests.integration.stack import Stack, running_stack

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]

NODES = [
    {"name": "node-01", "lat": 40.63431, "lon": -8.66012},
    {"name": "node-02", "lat": 40.63400, "lon": -8.65990},
]


@pytest.fixture
def roof_stack(tmp_path: Path) -> Iterator[Stack]:
    rail = json.loads(DEFAULT_RAIL_PATH.read_text())
    rail.update(name="IT1 roof with two nodes", nodes=NODES)
    rail_file = tmp_path / "rail.json"
    rail_file.write_text(json.dumps(rail))
    with running_stack(
        tmp_path / "var",
        broker_url=settings.CELERY_BROKER_URL,
        extra_env={"AGENT_RAIL_FILE": str(rail_file), "HEALTH_POLL_INTERVAL_S": "1"},
    ) as stack:
        yield stack


def _stop(process: subprocess.Popen[str]) -> None:
    """Kill, reap and close its pipe: an open pipe's warning fails whichever later test the
    garbage collector happens to run in."""
    process.kill()
    process.wait()
    if process.stdout is not None:
        process.stdout.close()


def _check_map(page: Page) -> None:
    roof = page.locator("#roof")
    expect(roof).to_have_attribute("data-ready", "1", timeout=15_000)
    svg = page.get_by_role("img", name="Map of mobile-1's rail on the roof, north up")
    expect(svg).to_be_visible()
    expect(svg.locator("desc")).to_contain_text("grid cells")
    labels = svg.locator(".roof-cell")
    expect(labels).to_have_count(16)
    expect(labels.first).to_have_text("A1")
    expect(svg.locator(".roof-node")).to_have_count(2)
    expect(svg.locator(".roof-label", has_text="node-02")).to_have_count(1)


def _moves(page: Page) -> None:
    """The robot's place on the map changes, and its words say it moves clockwise."""
    roof = page.locator("#roof")
    expect(roof).to_have_attribute("data-track-m", re.compile(r"^\d"), timeout=30_000)
    expect(page.locator("#roof-text")).to_contain_text("moving clockwise", timeout=30_000)
    # Both read at once: a reading may come between two separate reads.
    first, where = page.evaluate(
        "() => [document.getElementById('roof').dataset.trackM,"
        " document.getElementById('roof-robot').getAttribute('transform')]"
    )
    expect(roof).not_to_have_attribute("data-track-m", first, timeout=30_000)
    expect(page.locator("#roof-robot")).not_to_have_attribute("transform", where)
    expect(page.locator("#roof-text")).to_contain_text(
        re.compile(r"\d m along the rail, cell [A-D]\d")
    )


def _heat_shown_live(page: Page) -> None:
    """The series the pusher sends appears on the open page (no reload: the mark set on
    the page survives) and colours the roof's cells."""
    page.evaluate("() => { window.openedOnce = true; }")
    expect(page.locator("#measurement-rssi")).to_be_visible(timeout=30_000)
    expect(page.locator("#roof-heat-choice option")).to_have_text(["rssi (dBm)"])
    expect(page.locator("#roof .roof-heat-cell").first).to_be_attached(timeout=15_000)
    expect(page.locator("#roof-heat-legend")).to_contain_text("dBm")
    cells = page.locator("#roof").get_attribute("data-heat") or ""
    assert re.fullmatch(r"[A-D]\d( [A-D]\d)*", cells), cells
    # Each coloured cell is a row of the table the heatmap stands for.
    table = page.locator("#measurement-rssi table.measurement-cells tbody tr")
    assert set(cells.split()) <= set(table.evaluate_all("rows => rows.map(r => r.dataset.cell)"))
    assert page.evaluate("() => window.openedOnce === true")


def _cells_as_the_model_says(web: str, run_id: int, headers: dict[str, str], rail: Rail) -> None:
    """Each sample answered by one reading, placed on it; each cell's mean within four
    standard errors of the model's own mean at the cell's samples (the readings' shadowing is
    independent, so the mean of n readings has a standard deviation of shadowing_db / sqrt(n):
    a cell of one reading is off by more than shadowing_db a third of the time, by more than
    four times it once in 16,000)."""
    samples = all_samples(web, run_id, headers)
    series = requests.get(
        f"{web}/api/v1/runs/{run_id}/measurements/rssi/", headers=headers, timeout=10
    ).json()
    summary = series["summary"]["columns"]["rssi"]
    assert series["point_count"] == len(samples)
    assert summary["where"] == {"placed": len(samples), "before": 0, "after": 0, "gap": 0}
    model, node_at = PathLoss(), node_place(rail, "node-01", None)
    expected: dict[str, list[float]] = defaultdict(list)
    for sample in samples:
        if sample["grid_id"]:
            expected[sample["grid_id"]].append(
                model.mean_dbm(distance_m(rail, node_at, sample["track_m"]))
            )
    cells = {row["cell"]: row for row in summary["by_cell"]}
    assert len(cells) >= 2, summary["by_cell"]
    assert set(cells) == set(expected)
    for cell, values in expected.items():
        assert cells[cell]["count"] == len(values)
        model_mean = sum(values) / len(values)
        bound_db = 4 * model.shadowing_db / math.sqrt(len(values))
        assert abs(cells[cell]["mean"] - model_mean) <= bound_db, (cell, cells[cell], bound_db)


def test_the_roof_moves_on_the_run_page_and_the_console_during_a_run(
    browser, roof_stack, tmp_path, request
):
    MobileResourceFactory(agent_url=roof_stack.agent_url)
    UserFactory(username="root", is_staff=True, is_superuser=True)
    one_way = [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 20}]
    ines = Experimenter(roof_stack, "ines")
    errors: list[str] = []

    # Both pages sign in (and the console is open) before the run is booked, so only the run
    # page's own load stands between the booking and the run's 25 seconds: a slow machine
    # cannot let the run end before the page has seen it moving.
    context = browser.new_context(viewport={"width": 1280, "height": 1000})
    page = context.new_page()
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.on(
        "console",
        lambda m: "Content Security Policy" in m.text and errors.append(m.text),
    )
    login(page, roof_stack.web, "ines", "correct horse battery")

    console_context = browser.new_context(viewport={"width": 375, "height": 900})
    console = console_context.new_page()
    console.on("pageerror", lambda exc: errors.append(f"console: {exc}"))
    login(console, roof_stack.web, "root", "correct horse battery")
    console.goto(f"{roof_stack.web}/robot/mobile-1/")
    _check_map(console)

    run_id = ines.run("mobile-1", ahead_s=5, program_s=20, segments=one_way)
    token = ines.session.headers["Authorization"].removeprefix("Token ")
    pusher = subprocess.Popen(
        [sys.executable, "-m", "basestation.sim.rssi", "--portal", roof_stack.web,
         "--token", token, "--run", str(run_id), "--rail", str(tmp_path / "rail.json"),
         "--node", "node-01", "--poll-s", "0.5"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    request.addfinalizer(lambda: _stop(pusher))  # a test that failed early leaves none behind
    page.goto(f"{roof_stack.web}/runs/{run_id}/")
    _check_map(page)

    expect(page.locator("#run-state")).to_have_attribute("data-state", "running", timeout=30_000)
    # Both pages see the robot move before the heatmap is awaited: on a slow machine the first
    # readings can take longer to arrive than the program's 20 seconds of motion last.
    _moves(page)
    _moves(console)
    assert console.evaluate("document.documentElement.scrollWidth <= window.innerWidth + 1")
    console.screenshot(path=str(SCREENSHOTS / "roof-console-phone.png"), full_page=True)
    _heat_shown_live(page)
    page.screenshot(path=str(SCREENSHOTS / "roof-run-page.png"), full_page=True)

    # At the end the map stays on the run's last sample, standing still.
    expect(page.locator("#run-state")).to_have_attribute("data-state", "completed", timeout=60_000)
    expect(page.locator("#roof-text")).to_contain_text("At the run's last sample", timeout=15_000)
    output, _ = pusher.communicate(timeout=60)
    assert pusher.returncode == 0, output
    samples = len(all_samples(roof_stack.web, run_id, dict(ines.session.headers)))
    assert f"rssi: {samples} readings sent" in output, output
    rail = Rail.configured(str(tmp_path / "rail.json"))
    _cells_as_the_model_says(roof_stack.web, run_id, dict(ines.session.headers), rail)
    assert not errors, errors
    context.close()
    console_context.close()
