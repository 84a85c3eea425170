"""The run page's measurements: a file added on the page (the series shown with its cells and
charts' data), refused with the form's errors and nothing stored, a clock offset set again, a
series deleted after a confirmation; another user's run is not found. The same service as the
API (its audit rows say the door)."""

from __future__ import annotations

import json
import re
from typing import Any

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import Client

from core.audit.models import AuditEvent
from portal.runs.models import MeasurementPoint, MeasurementSeries
from tests.factories import MobileResourceFactory, UserFactory
from tests.runs.driving import completed_run

pytestmark = pytest.mark.django_db


@pytest.fixture
def alice(owner: Any) -> Client:
    client = Client()
    client.force_login(owner)
    return client


@pytest.fixture
def run(owner):
    return completed_run(owner, MobileResourceFactory(), [(0.5, "cw", 4.0)])


def _file(run, *, naive: bool = False) -> SimpleUploadedFile:
    t0_s = run.start_at.timestamp()
    if naive:
        return SimpleUploadedFile("walk.csv", b"t,rssi\n2027-01-01T10:00:00,-50\n")
    text = "t,rssi\n" + "".join(f"{t0_s + 0.25 * i:.6f},{-50 - i}\n" for i in range(12))
    return SimpleUploadedFile("walk.csv", text.encode())


def test_a_file_added_on_the_run_page_is_shown_placed(alice, run):
    page = alice.get(f"/runs/{run.pk}/")
    assert b'id="measurements-none"' in page.content
    added = alice.post(
        f"/runs/{run.pk}/measurements/", {"file": _file(run), "name": "rssi", "unit": "dBm"}
    )
    assert added.status_code == 302
    assert added["Location"].endswith(f"/runs/{run.pk}/#measurements")
    page = alice.get(f"/runs/{run.pk}/")
    text = page.content.decode()
    assert "Stored 12 values in rssi." in text
    assert 'id="measurement-rssi"' in text
    assert "12 on the robot&#x27;s path" in text or "12 on the robot's path" in text
    charts = json.loads(
        text.split('id="measurements-data" type="application/json">')[1].split("</script>")[0]
    )
    assert charts[0]["name"] == "rssi"
    assert len(charts[0]["columns"]["rssi"]["scatter"]["value"]) == 12
    assert AuditEvent.objects.get(action="measurement.add").data["via"] == "web"


def test_a_refused_file_shows_why_on_the_form_and_stores_nothing(alice, run):
    refused = alice.post(
        f"/runs/{run.pk}/measurements/", {"file": _file(run, naive=True), "name": "rssi"}
    )
    assert refused.status_code == 400
    text = refused.content.decode()
    assert "UTC offset" in text
    assert '<details id="measurement-add" open>' in text
    bad_name = alice.post(
        f"/runs/{run.pk}/measurements/", {"file": _file(run), "name": "RSSI walk"}
    )
    assert bad_name.status_code == 400
    assert not MeasurementSeries.objects.exists()
    assert not MeasurementPoint.objects.exists()


def test_an_offset_set_again_and_a_delete_that_asks_first(alice, run):
    alice.post(f"/runs/{run.pk}/measurements/", {"file": _file(run), "name": "rssi"})
    moved = alice.post(f"/runs/{run.pk}/measurements/rssi/offset/", {"clock_offset_s": "-30"})
    assert moved.status_code == 302
    series = MeasurementSeries.objects.get()
    assert series.clock_offset_s == -30.0
    assert series.summary["columns"]["rssi"]["where"]["before"] == 12
    asked = alice.get(f"/runs/{run.pk}/measurements/rssi/delete/")
    assert b"Yes, delete it" in asked.content
    assert MeasurementSeries.objects.exists()
    alice.post(f"/runs/{run.pk}/measurements/rssi/delete/")
    assert not MeasurementSeries.objects.exists()
    assert not MeasurementPoint.objects.exists()


def test_another_users_run_is_not_found_on_every_measurement_page(run):
    alice_file = _file(run)
    bob = Client()
    bob.force_login(UserFactory(username="bob"))
    MeasurementSeries.objects.create(run=run, name="rssi", columns=["rssi"])
    for answer in (
        bob.post(f"/runs/{run.pk}/measurements/", {"file": alice_file, "name": "mine"}),
        bob.post(f"/runs/{run.pk}/measurements/rssi/offset/", {"clock_offset_s": "1"}),
        bob.get(f"/runs/{run.pk}/measurements/rssi/delete/"),
        bob.post(f"/runs/{run.pk}/measurements/rssi/delete/"),
    ):
        assert answer.status_code == 404
    assert MeasurementSeries.objects.get().clock_offset_s == 0.0


def test_a_markers_suggested_offset_is_offered_and_used_with_one_button(alice, owner):
    from datetime import UTC, datetime

    from portal.runs.measurements import measurement_add, read_file_points
    from tests.runs.driving import run_round_the_rail

    run = run_round_the_rail(owner, seconds=10.0)
    t0_s = run.start_at.timestamp()
    text = "t,rssi\n" + "".join(f"{t0_s - 1.5 + 0.5 * i:.6f},-50\n" for i in range(10))
    measurement_add(
        run=run,
        by=owner,
        name="rssi",
        points=read_file_points(text.encode(), "csv"),
        marker_at=datetime.fromtimestamp(t0_s - 1.5, UTC),
    )
    page = alice.get(f"/runs/{run.pk}/").content.decode()
    assert "a clock offset of <strong>1.5 s</strong> aligns the two" in page
    assert 'data-testid="use-suggested-offset"' in page
    alice.post(f"/runs/{run.pk}/measurements/rssi/offset/", {"clock_offset_s": "1.5"})
    page = alice.get(f"/runs/{run.pk}/").content.decode()
    assert "and is the one used" in page
    assert 'data-testid="use-suggested-offset"' not in page


def test_the_series_part_is_the_pages_own_and_only_for_who_may_see_the_run(alice, run, other):
    empty = alice.get(f"/runs/{run.pk}/measurements/series/")
    assert empty.status_code == 200
    assert empty["Cache-Control"] == "private, no-store"
    assert 'id="measurements-none"' in empty.content.decode()
    alice.post(f"/runs/{run.pk}/measurements/", {"file": _file(run), "name": "rssi"})
    part = alice.get(f"/runs/{run.pk}/measurements/series/").content.decode()
    page = alice.get(f"/runs/{run.pk}/").content.decode()
    # The same markup as the page's (but each form's masked CSRF token): the script swaps
    # one for the other.
    part, page = (re.sub(r'name="csrfmiddlewaretoken" value="\w+"', "", t) for t in (part, page))
    start = page.index('<div id="measurement-series"')
    assert page[start : start + len(part.strip())] == part.strip()
    assert 'id="measurement-rssi"' in part
    stranger = Client()
    stranger.force_login(other)
    assert stranger.get(f"/runs/{run.pk}/measurements/series/").status_code == 404
