"""A campaign's results, download and end: the table's numbers are those worked out here from
the stored samples, the zip holds every completed run's package and a ``campaign.json`` that
Frictionless accepts, and ``campaign.done`` is recorded once, when the last run has ended.
Every clock here is fixed (the campaign's own dates, ``now=`` for the queue)."""

from __future__ import annotations

import io
import json
import statistics
import zipfile
from datetime import UTC, datetime

import pytest
from frictionless import validate

from core.events.dispatch import events_dispatch
from core.events.models import Event
from portal.queue.allocation import queue_allocate
from portal.queue.campaigns import campaign_cancel, campaign_create, campaign_done_check
from portal.queue.models import Campaign, QueueRequest
from portal.queue.results import campaign_results, campaign_runs_completed
from portal.runs.analysis import signed
from portal.runs.models import Run, Sample
from portal.runs.states import RunState
from tests.queue.campaign_runs import HZ, complete_with_samples

pytestmark = pytest.mark.django_db

NOW = datetime(2030, 1, 7, 9, 0, tzinfo=UTC)
SPEC = {
    "title": "velocity sweep",
    "robot": "mobile-1",
    "parameters": {"velocity_mps": [0.5, 1.0], "direction": ["cw", "ccw"], "duration_s": 3},
    "repeats": 2,
    "earliest_at": "2030-01-07T09:00:00Z",
    "latest_end_at": "2030-01-09T09:00:00Z",
}


@pytest.fixture
def campaign(owner, mobile, settings) -> Campaign:
    settings.QUEUE_LEAD_S = 0
    made = campaign_create(owner=owner, spec=SPEC)
    assert len(queue_allocate(now=NOW).booked) == 8
    return made


def _complete_all_but(campaign: Campaign, left: int = 0) -> list[QueueRequest]:
    requests = list(campaign.requests.select_related("reservation__run").order_by("pk"))
    for request in requests[: len(requests) - left]:
        assert request.reservation is not None
        assert request.parameters is not None
        complete_with_samples(request.reservation.run, request.parameters["repeat"])
    return requests


def _expected_from_samples(campaign: Campaign) -> dict[tuple[float, str], tuple[float, float]]:
    """Per (velocity, direction): the mean over repeats of each run's mean signed velocity,
    and their sample sd — from the stored samples, not the product's analysis."""
    per_run: dict[tuple[float, str], list[float]] = {}
    for request in campaign.requests.select_related("reservation__run"):
        assert request.reservation is not None
        assert request.parameters is not None
        rows = Sample.objects.filter(run=request.reservation.run, segment=0)
        measured = [signed(s.velocity_mps, s.direction) for s in rows]
        key = (request.parameters["velocity_mps"], request.parameters["direction"])
        per_run.setdefault(key, []).append(statistics.fmean(measured))
    return {k: (statistics.fmean(v), statistics.stdev(v)) for k, v in per_run.items()}


def test_the_results_table_is_the_stored_samples_mean_and_spread_over_repeats(campaign):
    _complete_all_but(campaign)
    groups = campaign_results(campaign_runs_completed(campaign))
    expected = _expected_from_samples(campaign)
    assert [(g.velocity_mps, g.direction) for g in groups] == sorted(expected)
    for group in groups:
        mean, sd = expected[(group.velocity_mps, group.direction)]
        spread = group.metrics["mean_mps"]
        assert spread.n == 2
        assert len(group.runs) == 2
        assert spread.mean == pytest.approx(mean, abs=1e-9)
        assert spread.sd == pytest.approx(sd, abs=1e-9)
        assert spread.sd > 0  # the repeats differ: a spread of zero would hide a mix-up
        assert group.metrics["duration_s"].mean == pytest.approx(3.0 - 1 / HZ)


def test_the_api_gives_the_same_results_and_only_to_whom_may_see_the_campaign(
    campaign, api, client_for, other
):
    _complete_all_but(campaign, left=2)
    answer = api.get(f"/api/v1/campaigns/{campaign.pk}/results/")
    assert answer.status_code == 200, answer.content
    body = answer.json()
    assert body["completed"] == 6
    groups = campaign_results(campaign_runs_completed(campaign))
    assert [g["runs"] for g in body["groups"]] == [list(g.runs) for g in groups]
    for got, group in zip(body["groups"], groups, strict=True):
        assert got["metrics"]["mean_mps"]["mean"] == pytest.approx(
            group.metrics["mean_mps"].mean, abs=1e-4
        )
    # One repeat only: a mean without a spread.
    assert any(g["metrics"]["mean_mps"]["sd"] is None for g in body["groups"])
    stranger = client_for(other)
    assert stranger.get(f"/api/v1/campaigns/{campaign.pk}/results/").status_code == 404
    assert stranger.get(f"/api/v1/campaigns/{campaign.pk}/package.zip").status_code == 404


def test_the_download_holds_each_completed_run_and_a_campaign_json_frictionless_accepts(
    campaign, api, tmp_path
):
    _complete_all_but(campaign, left=1)
    answer = api.get(f"/api/v1/campaigns/{campaign.pk}/package.zip")
    assert answer.status_code == 200
    assert f"amazing-campaign-{campaign.pk}.zip" in answer["Content-Disposition"]
    with zipfile.ZipFile(io.BytesIO(b"".join(answer.streaming_content))) as archive:
        archive.extractall(tmp_path)
        names = archive.namelist()
    descriptor = json.loads((tmp_path / "campaign.json").read_text())
    header, *rows = descriptor["resources"][0]["data"]
    assert len(rows) == 8
    by_request = {row[header.index("request")]: dict(zip(header, row, strict=True)) for row in rows}
    folders = {r["folder"] for r in by_request.values() if r["folder"]}
    assert len(folders) == 7
    assert {n.split("/")[0] + "/" for n in names if "/" in n} == folders
    for request in campaign.requests.all():
        row = by_request[request.pk]
        assert request.parameters is not None
        assert {k: row[k] for k in ("velocity_mps", "direction", "duration_s", "repeat")} == {
            k: request.parameters[k] for k in ("velocity_mps", "direction", "duration_s", "repeat")
        }
    results_header, *results = descriptor["resources"][1]["data"]
    assert len(results) == 4
    assert sum(r[results_header.index("repeats")] for r in results) == 7
    report = validate(str(tmp_path / "campaign.json"))
    assert report.valid, report.flatten(["rowNumber", "fieldName", "type", "note"])
    for folder in folders:
        package = validate(str(tmp_path / folder / "datapackage.json"))
        assert package.valid, package.flatten(["rowNumber", "fieldName", "type", "note"])


def test_campaign_done_is_recorded_once_when_the_last_run_has_ended(campaign):
    requests = _complete_all_but(campaign, left=1)
    assert campaign_done_check(campaign.pk) is False
    last = requests[-1]
    assert last.reservation is not None
    Run.objects.filter(pk=last.reservation.run.pk).update(state=RunState.FAILED)
    assert campaign_done_check(campaign.pk) is True
    assert campaign_done_check(campaign.pk) is False
    done = Event.objects.get(type="campaign.done")
    assert done.subject == f"campaign:{campaign.pk}"
    assert done.payload["runs"] == 8
    assert done.payload["ended"] == {"completed": 7, "failed": 1}
    campaign.refresh_from_db()
    assert campaign.done_at is not None


def test_a_campaign_whose_requests_were_withdrawn_is_done_through_its_handler(owner, mobile):
    made = campaign_create(owner=owner, spec={**SPEC, "repeats": 1})
    assert campaign_done_check(made.pk) is False  # four still waiting
    campaign_cancel(campaign=made, by=owner, cancel_booked=False, reason="wrong rail")
    assert not Event.objects.filter(type="campaign.done").exists()
    events_dispatch(name="campaign-done")
    done = Event.objects.get(type="campaign.done")
    assert done.payload["ended"] == {"cancelled": 4}
    assert done.payload["state"] == "cancelled"
    events_dispatch(name="campaign-done")
    assert Event.objects.filter(type="campaign.done").count() == 1
