"""Dry runs (``portal/runs/services/dry_run.py``): asked for, waiting in line for a place,
run in the simulator's own process, and never near a robot."""

from __future__ import annotations

import http.server
import json
import subprocess
import threading
from collections.abc import Iterator
from datetime import timedelta

import pytest
from django.db import IntegrityError, transaction
from django.utils import timezone

from core.errors import InvalidInput
from portal.runs import tasks
from portal.runs.models import DryRun
from portal.runs.selectors import dry_run_report
from portal.runs.services import dry_run as service
from portal.runs.services.dry_run import (
    dry_run_claim,
    dry_run_execute,
    dry_run_place,
    dry_run_request,
    dry_runs_next,
)
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory
from tests.runs.driving import ramped_travel

pytestmark = pytest.mark.django_db

PROGRAM = [
    {"velocity_mps": 0.5, "direction": "cw", "duration_s": 4.0},
    {"velocity_mps": 0.3, "direction": "ccw", "duration_s": 2.0},
]


@pytest.fixture
def kim():
    return UserFactory(username="kim")


@pytest.fixture
def robot():
    """A robot to book, whose limits the dry runs are tried under."""
    return MobileResourceFactory(max_velocity_mps=1.0)


def _ask(user, **experiment) -> DryRun:
    return dry_run_request(
        user=user, experiment=ExperimentFactory(owner=user, segments=PROGRAM, **experiment)
    )


def test_a_dry_run_takes_the_strictest_limits_of_the_robots_and_their_measured_rail(kim):
    MobileResourceFactory(name="mobile-1", max_velocity_mps=1.5, max_accel_mps2=0.8)
    MobileResourceFactory(name="mobile-2", max_velocity_mps=1.0, max_accel_mps2=1.2)
    dry_run = _ask(kim, title="sweep")
    assert dry_run.state == DryRun.State.QUEUED
    assert dry_run.title == "sweep"
    assert dry_run.segments == PROGRAM
    assert dry_run.limits == {"max_velocity_mps": 1.0, "max_accel_mps2": 0.8}
    assert dry_run.rail_length_m == service.DEFAULT_RAIL_LENGTH_M


def test_what_booking_would_refuse_is_refused_and_changes_nothing(kim, settings):
    MobileResourceFactory(max_velocity_mps=0.4)
    with pytest.raises(InvalidInput, match=r"Segment 0: velocity 0\.5 m/s exceeds the maximum of "):
        _ask(kim)
    with pytest.raises(InvalidInput, match="only your own"):
        dry_run_request(user=kim, experiment=ExperimentFactory(segments=PROGRAM))
    assert not DryRun.objects.exists()

    settings.DRY_RUN_MAX_WAITING = 2
    slow = [{"velocity_mps": 0.2, "direction": "cw", "duration_s": 1.0}]
    for _ in range(2):
        dry_run_request(user=kim, experiment=ExperimentFactory(owner=kim, segments=slow))
    with pytest.raises(InvalidInput, match="You have 2 dry runs waiting"):
        dry_run_request(user=kim, experiment=ExperimentFactory(owner=kim, segments=slow))
    assert DryRun.objects.count() == 2


def test_the_velocity_is_checked_by_bookings_own_rule_agent_limit_included(kim):
    # No robot to book: no limits to try under, and nothing is queued.
    with pytest.raises(InvalidInput, match="No robot can be booked now"):
        _ask(kim)
    # The portal allows 1 m/s, the robot's base station reports 0.4: booking holds the
    # program to 0.4 (``velocity_limit``), and so does the dry run, naming where it comes from.
    MobileResourceFactory(name="mobile-1", max_velocity_mps=1.0, agent_max_velocity_mps=0.4)
    with pytest.raises(InvalidInput, match=r"mobile-1: 0\.4 m/s, the limit its base station"):
        _ask(kim)
    assert not DryRun.objects.exists()
    slow = [{"velocity_mps": 0.4, "direction": "cw", "duration_s": 1.0}]
    dry_run = dry_run_request(user=kim, experiment=ExperimentFactory(owner=kim, segments=slow))
    assert dry_run.limits["max_velocity_mps"] == 0.4


def test_places_are_given_first_come_first_served_and_bounded_by_the_database(kim, robot, settings):
    settings.DRY_RUN_SLOTS = 2
    settings.DRY_RUN_MAX_WAITING = 10
    first, second, third = (_ask(kim) for _ in range(3))
    assert [dry_run_place(d) for d in (first, second, third)] == [1, 2, 3]
    assert dry_runs_next() == [first.pk, second.pk]
    # The third may not jump the line, and there is no third place.
    assert dry_run_claim(third.pk) is None
    assert dry_run_claim(second.pk) is not None
    assert dry_run_claim(first.pk) is not None
    assert dry_run_claim(first.pk) is None  # already running
    assert dry_run_claim(third.pk) is None
    third.refresh_from_db()
    assert dry_run_place(third) == 1
    assert sorted(DryRun.objects.filter(state="running").values_list("slot", flat=True)) == [0, 1]
    # Behind the rule, the database: no two running dry runs in one place.
    with pytest.raises(IntegrityError), transaction.atomic():
        DryRun.objects.filter(pk=third.pk).update(state="running", slot=0)


def test_a_dry_run_whose_worker_died_gives_its_place_to_the_next(kim, robot, settings):
    settings.DRY_RUN_SLOTS = 1
    lost, waiting = _ask(kim), _ask(kim)
    assert dry_run_claim(lost.pk) is not None
    assert dry_run_claim(waiting.pk) is None
    DryRun.objects.filter(pk=lost.pk).update(
        started_at=timezone.now() - timedelta(seconds=settings.DRY_RUN_STALE_S + 1)
    )
    assert dry_run_claim(waiting.pk) is not None
    lost.refresh_from_db()
    assert (lost.state, lost.slot) == (DryRun.State.FAILED, None)
    assert "try again" in lost.reason


class _Recorder(http.server.BaseHTTPRequestHandler):
    seen: list[str] = []

    def do_GET(self) -> None:
        self.seen.append(self.path)
        self.send_response(200)
        self.end_headers()

    do_PUT = do_POST = do_GET

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def base_station() -> Iterator[str]:
    """A web server standing for a robot's base station, recording every request."""
    _Recorder.seen = []
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Recorder)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    thread.join()
    server.server_close()


def test_a_dry_run_runs_in_its_own_process_and_never_reaches_a_robot(
    kim, base_station, monkeypatch
):
    MobileResourceFactory(agent_url=base_station, max_velocity_mps=1.0, max_accel_mps2=1.0)
    started: list[dict] = []
    real_run = subprocess.run

    def run_and_record(argv, **kwargs):
        started.append({"argv": argv, **kwargs})
        return real_run(argv, **kwargs)

    monkeypatch.setattr(service.subprocess, "run", run_and_record)
    dry_run = _ask(kim)
    assert dry_run_execute(dry_run.pk) is True
    dry_run.refresh_from_db()
    assert dry_run.state == DryRun.State.COMPLETED, dry_run.reason
    assert (dry_run.slot, dry_run.reason) == (None, "")
    assert len(dry_run.samples) >= 6 * 20

    # What the process was given: the program, limits and rail; nothing that names a robot.
    [process] = started
    assert process["argv"][1:] == ["-m", "basestation.dryrun"]
    assert set(json.loads(process["input"])) == {"segments", "limits", "rail_length_m"}
    assert set(process["env"]) == {"PATH", "LANG"}
    for text in (process["input"], json.dumps(process["env"]), json.dumps(dry_run.samples)):
        assert base_station not in text
    assert _Recorder.seen == []

    report = dry_run_report(dry_run=dry_run)
    assert report.analysis.samples == len(dry_run.samples)
    assert [s.samples > 0 for s in report.analysis.segments] == [True, True]
    program = [(s["velocity_mps"], s["direction"], s["duration_s"]) for s in PROGRAM]
    distance_m, displacement_m = ramped_travel(program, accel_mps2=1.0)
    assert report.analysis.distance_m == pytest.approx(distance_m, abs=0.05)
    assert dry_run.samples[-1]["track_m"] == pytest.approx(displacement_m, abs=0.05)
    assert set(report.series) >= {"commanded_mps", "measured_mps", "track_m", "battery_v"}


def test_a_simulator_that_fails_fails_the_dry_run_with_its_reason(kim, monkeypatch):
    MobileResourceFactory()

    def broken(argv, **kwargs):
        return subprocess.CompletedProcess(
            argv, 1, stdout="", stderr="Traceback\nOSError: disk full"
        )

    monkeypatch.setattr(service.subprocess, "run", broken)
    dry_run = _ask(kim)
    dry_run_execute(dry_run.pk)
    dry_run.refresh_from_db()
    assert (dry_run.state, dry_run.slot) == (DryRun.State.FAILED, None)
    assert dry_run.reason == "The simulator failed: OSError: disk full"


def test_the_pages_start_show_and_refuse_as_they_should(
    kim, client, monkeypatch, django_capture_on_commit_callbacks
):
    # The page is seen while the dry run waits in line: what starting it queues after the
    # commit is recorded here, not run.
    queued: list[tuple[int, ...]] = []
    monkeypatch.setattr(tasks.dry_run_execute, "delay", lambda *args: queued.append(args))
    MobileResourceFactory(max_velocity_mps=0.4)
    client.force_login(kim)
    too_fast = ExperimentFactory(owner=kim, segments=PROGRAM)
    with django_capture_on_commit_callbacks(execute=True):
        answer = client.post(f"/experiments/{too_fast.pk}/dry-run/", follow=True)
    assert answer.redirect_chain == [(f"/experiments/{too_fast.pk}/", 302)]
    assert (
        "Not tried: Segment 0: velocity 0.5 m/s exceeds the maximum of " in answer.content.decode()
    )
    assert not DryRun.objects.exists()
    assert queued == []

    slow = ExperimentFactory(owner=kim, segments=[dict(PROGRAM[1])])
    with django_capture_on_commit_callbacks(execute=True):
        answer = client.post(f"/experiments/{slow.pk}/dry-run/")
    dry_run = DryRun.objects.get()
    assert queued == [(dry_run.pk,)]
    assert answer.headers["Location"] == f"/dry-runs/{dry_run.pk}/"
    page = client.get(f"/dry-runs/{dry_run.pk}/").content.decode()
    assert "simulated" in page
    assert "Place in line: 1." in page
    data = client.get(f"/dry-runs/{dry_run.pk}/data.json").json()
    assert (data["state"], data["place"], data["live"], data["sample_count"]) == (
        "queued",
        1,
        True,
        0,
    )

    # Someone else's dry run and experiment are not there at all.
    client.force_login(UserFactory(username="lee"))
    assert client.get(f"/dry-runs/{dry_run.pk}/").status_code == 404
    assert client.get(f"/dry-runs/{dry_run.pk}/data.json").status_code == 404
    assert client.post(f"/experiments/{slow.pk}/dry-run/").status_code == 404
    assert DryRun.objects.count() == 1
