"""Measurements added on the run page in Chromium: a file chosen and sent, the series shown
placed (its cells as a table, its charts drawn); a bad file answered on the form, beside the
field, with nothing stored."""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from portal.runs.models import MeasurementSeries
from tests.browser.conftest import SCREENSHOTS, login
from tests.factories import UserFactory
from tests.runs.driving import run_round_the_rail

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]


@pytest.mark.parametrize(("name", "width"), [("laptop", 1280), ("phone", 375)])
def test_a_file_added_on_the_run_page_is_shown_on_the_path(
    browser, live_server, tmp_path, name, width
):
    owner = UserFactory(username="hal")
    run = run_round_the_rail(owner, speed_mps=2.0, seconds=30.0)
    t0_s = run.start_at.timestamp()
    good = tmp_path / "walk.csv"
    good.write_text(
        "t,rssi\n" + "".join(f"{t0_s + 0.1 * i:.6f},{-40 - i % 30}\n" for i in range(280))
    )
    bad = tmp_path / "naive.csv"
    bad.write_text("t,rssi\n2027-03-28T10:00:00,-50\n")
    context = browser.new_context(viewport={"width": width, "height": 900})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    login(page, live_server.url, "hal", "correct horse battery")
    page.goto(f"{live_server.url}/runs/{run.pk}/")
    section = page.locator("#measurements")
    expect(section.locator("#measurements-none")).to_be_visible()

    section.get_by_text("Add measurements").click()
    section.get_by_label("File (CSV, JSON or Parquet)").set_input_files(str(bad))
    section.get_by_label("Series name").fill("rssi")
    section.get_by_role("button", name="Add to this run").click()
    expect(page.locator("#id_file-error")).to_contain_text("UTC offset")
    assert not MeasurementSeries.objects.exists()

    section = page.locator("#measurements")
    section.get_by_label("File (CSV, JSON or Parquet)").set_input_files(str(good))
    section.get_by_label("Series name").fill("rssi")
    section.get_by_label("Unit").fill("dBm")
    section.get_by_role("button", name="Add to this run").click()
    expect(page.get_by_text("Stored 280 values in rssi.")).to_be_visible()
    cells = page.locator("table.measurement-cells tbody tr")
    expect(cells.first).to_be_visible()
    assert cells.count() >= 5  # 56 m of a 10 m-celled rail
    expect(page.locator("#measurement-rssi")).to_contain_text("280 on the robot")
    page.wait_for_function(
        "() => Chart.getChart('m-1-1-position').data.datasets[0].data.length === 280",
        timeout=15_000,
    )
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    # The section's picture (docs/screenshots with `make screenshots`).
    page.locator("#measurements").screenshot(
        path=str(SCREENSHOTS / f"measurements-{name}.jpg"), type="jpeg", quality=70
    )
    assert not errors, errors
    context.close()
