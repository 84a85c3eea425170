"""`amazing queue`: ask for a run as soon as possible, see its place and estimated start,
withdraw it; against the real web process."""

from __future__ import annotations

import json
import zipfile
from datetime import UTC, datetime, timedelta

import pytest
from typer.testing import CliRunner

from amazing_cli.main import app
from bookings.models import Reservation, ReservationItem
from portal.queue.allocation import queue_allocate
from portal.queue.models import Campaign, QueueRequest, RequestState
from portal.queue.results import campaign_results, campaign_runs_completed
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory, api_token
from tests.queue.campaign_runs import complete_with_samples

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]


def amazing(*args: str):
    return CliRunner().invoke(app, list(args), catch_exceptions=False)


@pytest.fixture
def fay(live_web, monkeypatch, tmp_path):
    fay = UserFactory(username="fay")
    monkeypatch.setenv("AMAZING_URL", live_web.url)
    monkeypatch.setenv("AMAZING_TOKEN", api_token(fay))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("COLUMNS", "200")
    return fay


def test_a_request_is_queued_listed_with_its_estimate_and_withdrawn(fay):
    robot = MobileResourceFactory(agent_url="http://127.0.0.1:9")
    experiment = ExperimentFactory(owner=fay, title="sweep 0.5")
    # A far-off day whose morning is taken until 10:00 UTC: the estimate is then.
    day = datetime(2031, 3, 4, tzinfo=UTC)
    taken = Reservation.objects.create(
        owner=UserFactory(username="gil"), start_at=day, end_at=day + timedelta(hours=10)
    )
    ReservationItem.objects.create(
        reservation=taken, resource=robot, start_at=taken.start_at, end_at=taken.end_at
    )
    made = amazing(
        "queue", "add", str(experiment.pk), "--earliest", "2031-03-04T00:00Z",
        "--by", "2031-03-06T00:00Z", "--json",
    )  # fmt: skip
    assert made.exit_code == 0, made.stderr
    body = json.loads(made.stdout)
    assert (body["state"], body["position"]) == ("waiting", 1)
    assert body["estimated_start_at"] == "2031-03-04T10:00:00Z"

    listed = amazing("queue", "list")
    assert listed.exit_code == 0, listed.stderr
    assert (
        f"{body['id']}  sweep 0.5 on mobile-1: waiting, place 1, estimated start" in listed.stdout
    )

    bad = amazing("queue", "add", str(experiment.pk), "--by", "2031-03-06T00:00Z", "--hours", "x")
    assert bad.exit_code == 2
    refused = amazing("queue", "add", str(experiment.pk), "--by", "+1s")
    assert refused.exit_code == 2, (refused.stdout, refused.stderr)
    assert "latest end" in refused.stderr
    assert QueueRequest.objects.count() == 1

    gone = amazing("queue", "cancel", str(body["id"]), "--reason", "done by hand")
    assert gone.exit_code == 0, gone.stderr
    assert QueueRequest.objects.get().state == RequestState.CANCELLED
    assert "Nothing waiting" in amazing("queue", "list").stdout


def test_a_campaign_file_is_queued_followed_and_cancelled(fay, tmp_path):
    MobileResourceFactory(agent_url="http://127.0.0.1:9")
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(
        "title: velocity sweep\n"
        "robot: mobile-1\n"
        "parameters:\n"
        "  velocity_mps: {from: 0.5, to: 1.0, step: 0.5}\n"
        "  direction: [cw, ccw]\n"
        "  duration_s: 5\n"
        "repeats: 2\n"
        "earliest_at: 2031-03-04T00:00:00Z\n"  # a YAML timestamp: sent as RFC 3339
        "latest_end_at: '2031-03-06T00:00:00+00:00'\n"
    )
    made = amazing("campaign", "create", str(sweep), "--json")
    assert made.exit_code == 0, made.stderr
    campaign = json.loads(made.stdout)
    assert campaign["progress"] == {"runs": 8, "queue": {"waiting": 8}, "run_states": {}}
    status = amazing("campaign", "status", str(campaign["id"]))
    assert status.exit_code == 0, status.stderr
    assert "8 runs; queue: 8 waiting" in status.stdout
    assert "0.5 m/s cw 5 s, repeat 1: waiting" in status.stdout

    bad = tmp_path / "bad.yaml"
    bad.write_text(sweep.read_text().replace("repeats: 2", "repeats: 2\ngain: 3"))
    refused = amazing("campaign", "create", str(bad))
    assert refused.exit_code == 2, (refused.stdout, refused.stderr)
    assert "gain" in refused.stderr
    assert QueueRequest.objects.count() == 8

    gone = amazing("campaign", "cancel", str(campaign["id"]))
    assert gone.exit_code == 0, gone.stderr
    assert "8 cancelled" in gone.stdout


def test_a_campaign_is_paused_resumed_and_its_results_shown_and_downloaded(fay, tmp_path, settings):
    MobileResourceFactory(agent_url="http://127.0.0.1:9")
    sweep = tmp_path / "sweep.json"
    sweep.write_text(
        json.dumps(
            {
                "title": "two speeds",
                "robot": "mobile-1",
                "parameters": {"velocity_mps": [0.5, 1.0], "direction": "cw", "duration_s": 3},
                "repeats": 2,
                "earliest_at": "2031-03-04T00:00:00Z",
                "latest_end_at": "2031-03-06T00:00:00Z",
            }
        )
    )
    made = amazing("campaign", "create", str(sweep), "--quiet")
    assert made.exit_code == 0, made.stderr
    campaign_id = made.stdout.strip()
    paused = amazing("campaign", "pause", campaign_id)
    assert "(paused)" in paused.stdout, paused.stdout
    assert Campaign.objects.get(pk=campaign_id).state == "paused"
    resumed = amazing("campaign", "resume", campaign_id)
    assert "(active)" in resumed.stdout, resumed.stdout

    # The queue books them (the clock is the campaign's, far ahead) and the runs complete.
    settings.QUEUE_LEAD_S = 0
    assert len(queue_allocate(now=datetime(2031, 3, 4, tzinfo=UTC)).booked) == 4
    requests = Campaign.objects.get(pk=campaign_id).requests.select_related("reservation__run")
    for request in requests:
        complete_with_samples(request.reservation.run, request.parameters["repeat"])
    expected = campaign_results(campaign_runs_completed(Campaign.objects.get(pk=campaign_id)))

    status = amazing("campaign", "status", campaign_id)
    assert status.exit_code == 0, status.stderr
    assert "Results of 4 completed runs" in status.stdout
    for group in expected:
        velocity = group.metrics["mean_mps"]
        assert velocity.sd is not None
        # As the API gives them (to 4 places), printed to 3.
        shown = f"{round(velocity.mean, 4):.3f} ± {round(velocity.sd, 4):.3f}"
        assert shown in status.stdout, status.stdout

    target = tmp_path / "sweep.zip"
    downloaded = amazing("campaign", "download", campaign_id, "-o", str(target))
    assert downloaded.exit_code == 0, downloaded.stderr
    assert f"Wrote {target}: 4 of 4 runs' packages and campaign.json" in downloaded.stdout
    with zipfile.ZipFile(target) as archive:
        descriptor = json.loads(archive.read("campaign.json"))
        folders = {name.split("/")[0] for name in archive.namelist() if "/" in name}
    assert len(folders) == 4
    assert descriptor["amazing"]["campaign"]["file"]["title"] == "two speeds"

    missing = amazing("campaign", "download", "999999", "-o", str(tmp_path / "none.zip"))
    assert missing.exit_code != 0
    assert not (tmp_path / "none.zip").exists()
