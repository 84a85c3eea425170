"""`amazing attach`: a booking made through the lease API gets its experiment from the CLI."""

from __future__ import annotations

import json
from datetime import timedelta

import pytest
from django.contrib.auth.models import Permission
from django.utils import timezone
from typer.testing import CliRunner

from amazing_cli.main import app
from bookings.choices import BookedVia
from bookings.services import reservation_create
from portal.runs.models import Run
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory, api_token

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]


@pytest.fixture
def leased(live_web, monkeypatch, tmp_path):
    """erin's robot booking made through the lease API, and erin's token in the environment."""
    robot = MobileResourceFactory(agent_url="http://127.0.0.1:9")
    erin = UserFactory(username="erin")
    account = UserFactory(username="testbed-scheduler")
    account.user_permissions.add(Permission.objects.get(codename="lease_inbound"))
    monkeypatch.setenv("AMAZING_URL", live_web.url)
    monkeypatch.setenv("AMAZING_TOKEN", api_token(erin))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("COLUMNS", "160")
    start = timezone.now().replace(microsecond=0) + timedelta(hours=2)
    return reservation_create(
        owner=erin,
        resources=[robot],
        start_at=start,
        end_at=start + timedelta(minutes=30),
        by=account,
        program_required=False,
        booked_via=BookedVia.SCHEDULER,
    )


def amazing(*args: str):
    return CliRunner().invoke(app, list(args), catch_exceptions=False)


def test_attach_gives_the_booking_its_run_and_refuses_a_second(leased):
    experiment = ExperimentFactory(owner=leased.owner, title="attached")
    done = amazing("attach", str(leased.pk), "--experiment", str(experiment.pk))
    assert done.exit_code == 0, done.stderr
    run = Run.objects.get(reservation=leased)
    assert f"Reservation {leased.pk} runs experiment {experiment.pk} as run {run.pk}" in (
        done.stdout
    )
    assert run.experiment == experiment
    again = amazing("attach", str(leased.pk), "-e", str(experiment.pk), "--json")
    assert again.exit_code == 3, (again.stdout, again.stderr)  # refused
    assert "already has its experiment" in again.stderr
    assert Run.objects.count() == 1


def test_attach_as_json_and_unknown_ids(leased):
    experiment = ExperimentFactory(owner=leased.owner)
    unknown = amazing("attach", "999999", "-e", str(experiment.pk))
    assert unknown.exit_code == 4
    assert not Run.objects.exists()
    done = amazing("attach", str(leased.pk), "-e", str(experiment.pk), "--json")
    assert done.exit_code == 0, done.stderr
    body = json.loads(done.stdout)
    assert body["run"]["state"] == "scheduled"
    assert body["resources"] == ["mobile-1"]
