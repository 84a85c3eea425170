"""``/api/v1/runs/{id}/measurements/``: a file uploaded, batches sent, a clock offset set, a
series deleted; the run's owner and staff only, bad input refused with nothing stored."""

from __future__ import annotations

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import override_settings

from core.audit.models import AuditEvent
from portal.runs.models import MeasurementPoint, MeasurementSeries
from tests.factories import MobileResourceFactory
from tests.runs.driving import completed_run

pytestmark = pytest.mark.django_db


@pytest.fixture
def owner_api(api):
    return api


@pytest.fixture
def other_api(client_for, other):
    return client_for(other)


@pytest.fixture
def admin_api(client_for, admin_user):
    return client_for(admin_user)


@pytest.fixture
def run(owner):
    return completed_run(owner, MobileResourceFactory(), [(0.5, "cw", 4.0)])


def _csv(run, n: int = 10, *, name: str = "walk.csv") -> SimpleUploadedFile:
    t0_s = run.start_at.timestamp()
    text = "t,rssi\n" + "".join(f"{t0_s + 0.3 * i:.3f},{-55 - i}\n" for i in range(n))
    return SimpleUploadedFile(name, text.encode(), content_type="text/csv")


def _url(run, name: str = "") -> str:
    return f"/api/v1/runs/{run.pk}/measurements/" + (f"{name}/" if name else "")


def test_the_owner_uploads_a_file_and_the_same_file_again_stores_once(owner_api, run):
    made = owner_api.post(
        _url(run), {"file": _csv(run), "name": "rssi", "unit": "dBm"}, format="multipart"
    )
    assert made.status_code == 201, made.json()
    body = made.json()
    assert (body["stored"], body["already"]) == (10, 0)
    assert body["series"]["unit"] == "dBm"
    assert body["series"]["columns"] == ["rssi"]
    assert body["series"]["summary"]["columns"]["rssi"]["points"] == 10
    again = owner_api.post(_url(run), {"file": _csv(run), "name": "rssi"}, format="multipart")
    assert again.status_code == 200
    assert (again.json()["stored"], again.json()["already"]) == (0, 10)
    assert MeasurementPoint.objects.count() == 10
    listed = owner_api.get(_url(run)).json()
    assert [series["name"] for series in listed] == ["rssi"]
    audit = AuditEvent.objects.filter(action="measurement.add").first()
    assert audit is not None
    assert audit.data["via"] == "api"


def test_batches_during_the_run_add_up_and_an_offset_moves_them(owner_api, run):
    t0_s = run.start_at.timestamp()
    for first in (0, 5):
        sent = owner_api.post(
            _url(run, "rssi"),
            {"points": [{"t": t0_s + 0.5 * i, "rssi": -60.0 - i} for i in range(first, first + 5)]},
            format="json",
        )
        assert sent.status_code == (201 if first == 0 else 200), sent.json()
    series = owner_api.get(_url(run, "rssi")).json()
    assert series["point_count"] == 10
    moved = owner_api.patch(_url(run, "rssi"), {"clock_offset_s": -100.0}, format="json")
    assert moved.status_code == 200
    assert moved.json()["summary"]["columns"]["rssi"]["where"]["before"] == 10


def test_bad_input_is_refused_and_nothing_is_stored(owner_api, run):
    cases = [
        (
            {"file": SimpleUploadedFile("a.csv", b"t,rssi\n1795000000,loud\n"), "name": "rssi"},
            "file",
        ),
        ({"file": _csv(run), "name": "RSSI walk"}, "name"),
        ({"file": _csv(run, name="walk.xlsx"), "name": "rssi"}, "format"),
        ({"file": _csv(run), "name": "rssi", "columns": "snr"}, "file"),
        ({"name": "rssi"}, "file"),
    ]
    for data, field in cases:
        refused = owner_api.post(_url(run), data, format="multipart")
        assert refused.status_code == 400, refused.json()
        assert field in refused.json()["fields"], refused.json()
    batch = owner_api.post(_url(run, "rssi"), {"points": [{"t": "noon", "rssi": 1}]}, format="json")
    assert batch.status_code == 400
    assert "points" in batch.json()["fields"]
    assert not MeasurementSeries.objects.exists()
    assert not MeasurementPoint.objects.exists()
    assert not AuditEvent.objects.filter(action__startswith="measurement.").exists()


@override_settings(MEASUREMENT_MAX_UPLOAD_BYTES=100)
def test_a_file_over_the_limit_is_refused_with_413(owner_api, run):
    refused = owner_api.post(_url(run), {"file": _csv(run, 50), "name": "rssi"}, format="multipart")
    assert refused.status_code == 413
    assert "MEASUREMENT_MAX_UPLOAD_BYTES" in refused.json()["detail"]
    assert not MeasurementSeries.objects.exists()


def test_another_user_finds_nothing_and_staff_may(owner_api, other_api, admin_api, run):
    owner_api.post(_url(run), {"file": _csv(run), "name": "rssi"}, format="multipart")
    for answer in (
        other_api.get(_url(run)),
        other_api.get(_url(run, "rssi")),
        other_api.post(_url(run), {"file": _csv(run), "name": "mine"}, format="multipart"),
        other_api.post(_url(run, "rssi"), {"points": [{"t": 1, "rssi": 1}]}, format="json"),
        other_api.patch(_url(run, "rssi"), {"clock_offset_s": 1.0}, format="json"),
        other_api.delete(_url(run, "rssi")),
    ):
        assert answer.status_code == 404
    assert MeasurementSeries.objects.get().clock_offset_s == 0.0
    assert admin_api.get(_url(run, "rssi")).status_code == 200
    assert admin_api.delete(_url(run, "rssi")).status_code == 204
    assert not MeasurementPoint.objects.exists()


def test_an_unknown_series_is_404(owner_api, run):
    assert owner_api.get(_url(run, "nothing")).status_code == 404
    assert owner_api.delete(_url(run, "nothing")).status_code == 404


def test_the_amazing_commands_door_is_named_in_the_audit(owner_api, run):
    sent = owner_api.post(
        _url(run),
        {"file": _csv(run), "name": "rssi"},
        format="multipart",
        HTTP_X_AMAZING_CLIENT="cli",
    )
    assert sent.status_code == 201
    assert AuditEvent.objects.get(action="measurement.add").data["via"] == "cli"
