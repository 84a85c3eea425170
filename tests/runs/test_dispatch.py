"""Staging and collection against the real agent application over HTTP.

The agent runs in-process behind a real HTTP server, without its control-loop thread: the
test advances its clock tick by tick, so every state of a run can be observed exactly.
"""

from __future__ import annotations

from datetime import timedelta

import jsonschema
import pytest
from django.utils import timezone

from basestation.client import AgentError
from bookings.choices import ReservationState
from core.events.catalogue import EVENT_TYPES
from core.events.models import Event
from core.events.sequence import events_sequence
from portal.runs import tasks
from portal.runs.models import Run, Sample
from portal.runs.services import collection, staging
from portal.runs.services.reservations import reservation_cancel, reservation_create
from portal.runs.states import RunState
from tests.factories import ExperimentFactory

pytestmark = pytest.mark.django_db

TICK_S = 0.05


@pytest.fixture
def booked(agent, owner, mobile):
    mobile.agent_url = agent.url
    mobile.save()
    experiment = ExperimentFactory(
        owner=owner,
        segments=[
            {"velocity_mps": 0.5, "direction": "cw", "duration_s": 2.0},
            {"velocity_mps": 0.5, "direction": "ccw", "duration_s": 2.0},
        ],
    )
    start = timezone.now() + timedelta(minutes=2)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(seconds=10),
        experiment=experiment,
    )
    return Run.objects.get(reservation=reservation)


def _state(run: Run) -> str:
    run.refresh_from_db()
    return run.state


def test_staging_puts_the_program_on_the_agent_once(agent, booked):
    staging.run_stage(run_id=booked.pk)
    assert _state(booked) == RunState.STAGED
    on_agent = agent.client.get_run(booked.agent_run_id)
    assert on_agent["state"] == "staged"
    assert on_agent["segments"] == booked.segments
    assert on_agent["owner"] == "alice"
    staging.run_stage(run_id=booked.pk)  # already past this step: nothing happens
    assert [e.to_state for e in booked.events.all()] == ["scheduled", "staged"]


def test_a_conflicting_run_on_the_agent_fails_the_run_with_the_reason(agent, booked):
    body = staging.run_agent_body(booked)
    body["title"] = "something else"
    agent.client.put_run(booked.agent_run_id, body)
    staging.run_stage(run_id=booked.pk)
    assert _state(booked) == RunState.FAILED
    assert "refused" in booked.reason


def test_an_unreachable_agent_is_a_retryable_error_and_changes_nothing(booked, mobile):
    mobile.agent_url = "http://127.0.0.1:9"  # discard port: nothing listens
    mobile.save()
    with pytest.raises(AgentError) as excinfo:
        staging.run_stage(run_id=booked.pk)
    assert excinfo.value.retryable
    assert _state(booked) == RunState.SCHEDULED


def test_a_run_not_staged_before_its_end_fails(agent, booked):
    staging.run_stage(run_id=booked.pk, now=booked.end_at + timedelta(seconds=1))
    assert _state(booked) == RunState.FAILED
    assert "before the reservation ended" in booked.reason


def test_collection_follows_the_run_and_verifies_the_count(agent, booked):
    staging.run_stage(run_id=booked.pk)
    start_s = booked.start_at.timestamp()
    agent.run_clock(start_s, start_s + 1.0)
    collection.run_collect(run_id=booked.pk)
    assert _state(booked) == RunState.RUNNING
    partial = Sample.objects.filter(run=booked).count()
    assert partial == agent.client.get_run(booked.agent_run_id)["sample_count"] > 0

    agent.run_clock(start_s + 1.0 + TICK_S, start_s + 9.0)
    collection.run_collect(run_id=booked.pk)
    collection.run_collect(run_id=booked.pk)  # a duplicate collection stores nothing twice
    on_agent = agent.client.get_run(booked.agent_run_id)
    assert on_agent["state"] == "completed"
    assert _state(booked) == RunState.COMPLETED
    seqs = list(Sample.objects.filter(run=booked).values_list("seq", flat=True))
    assert seqs == list(range(1, on_agent["sample_count"] + 1))
    assert booked.agent_sample_count == on_agent["sample_count"]
    assert booked.reservation.state == ReservationState.COMPLETED
    # Laps and passes are counted on the portal: it keeps the length the track wraps at.
    assert booked.rail_length_m == on_agent["rail_length_m"] > 0
    assert [e.to_state for e in booked.events.all()] == [
        "scheduled",
        "staged",
        "running",
        "collecting",
        "completed",
    ]
    # A collection that overlapped the one that ended it changes nothing of the record.
    provenance = Run.objects.get(pk=booked.pk).provenance
    view = collection._look(booked, agent.client)
    assert view is not None
    collection._close(booked, view, RunState.COMPLETED, timezone.now())
    assert Run.objects.get(pk=booked.pk).provenance == provenance
    # Then its data are ready, once, saying where to fetch them.
    events_sequence()
    events = list(Event.objects.filter(subject=f"run:{booked.pk}").order_by("seq"))
    assert [e.type for e in events][-2:] == ["run.completed", "run.data_ready"]
    ready = events[-1]
    assert ready.owner_id == booked.reservation.owner_id
    jsonschema.validate(ready.payload, EVENT_TYPES["run.data_ready"].payload)
    assert ready.payload["samples"] == on_agent["sample_count"]
    assert ready.payload["missing"] == 0
    assert ready.payload["files"]["csv"] == f"/api/v1/runs/{booked.pk}/samples.csv"


@pytest.mark.parametrize("reported", [None, 0, -5.0, "120", True, float("nan")])
def test_a_missing_or_unusable_rail_length_is_left_unset(agent, booked, monkeypatch, reported):
    real_get_run = type(agent.client).get_run

    def get_run(client, run_id):
        answer = real_get_run(client, run_id)
        if reported is None:
            del answer["rail_length_m"]
        else:
            answer["rail_length_m"] = reported
        return answer

    monkeypatch.setattr(type(agent.client), "get_run", get_run)
    staging.run_stage(run_id=booked.pk)
    start_s = booked.start_at.timestamp()
    agent.run_clock(start_s, start_s + 1.0)
    collection.run_collect(run_id=booked.pk)
    assert _state(booked) == RunState.RUNNING  # collection itself goes on
    assert booked.rail_length_m is None


def test_cancelling_a_staged_run_withdraws_it_from_the_agent(agent, booked, owner):
    staging.run_stage(run_id=booked.pk)
    reservation_cancel(reservation=booked.reservation, by=owner)
    staging.run_unstage(run_id=booked.pk)  # what the task queued on commit does
    assert _state(booked) == RunState.CANCELLED
    assert agent.client.get_run(booked.agent_run_id)["state"] == "cancelled"


def test_cancelling_a_running_run_aborts_it_and_keeps_the_data(agent, booked, owner):
    staging.run_stage(run_id=booked.pk)
    start_s = booked.start_at.timestamp()
    agent.run_clock(start_s, start_s + 1.0)
    collection.run_collect(run_id=booked.pk)
    reservation_cancel(reservation=booked.reservation, by=owner)
    staging.run_unstage(run_id=booked.pk)
    assert _state(booked) == RunState.RUNNING  # still to be collected
    agent.run_clock(start_s + 1.0 + TICK_S, start_s + 2.0)
    collection.run_collect(run_id=booked.pk)
    assert _state(booked) == RunState.INTERRUPTED
    on_agent = agent.client.get_run(booked.agent_run_id)
    assert Sample.objects.filter(run=booked).count() == on_agent["sample_count"] > 0
    ready = Event.objects.get(subject=f"run:{booked.pk}", type="run.data_ready")
    assert (ready.payload["state"], ready.payload["samples"]) == (
        "interrupted",
        on_agent["sample_count"],
    )
    assert ready.payload["missing"] >= 1  # the program's rest, never driven


def test_a_run_that_ended_without_samples_has_no_data_ready(agent, booked):
    staging.run_stage(run_id=booked.pk)
    collection._close_unreachable(booked, AgentError("gone", retryable=True, status=None))
    assert _state(booked) == RunState.FAILED
    assert not Event.objects.filter(type="run.data_ready").exists()


# -- a cancel through its real paths: the commit hook, and the sweep when the hook's task is lost


def _stage_and_start(agent, run: Run) -> float:
    """Stage ``run``, drive the robot one second into it, collect: running on both sides."""
    staging.run_stage(run_id=run.pk)
    start_s = run.start_at.timestamp()
    agent.run_clock(start_s, start_s + 1.0)
    collection.run_collect(run_id=run.pk)
    assert _state(run) == RunState.RUNNING
    return start_s + 1.0


def _cancel(run: Run, owner, capture, *, hooks_run: bool) -> None:
    """Cancel the booking as the API does; its commit hooks run, or are lost with the task
    they queue (a worker or broker that went down)."""
    with capture(execute=hooks_run):
        reservation_cancel(reservation=run.reservation, by=owner)
    run.reservation.refresh_from_db()
    assert run.reservation.state == ReservationState.CANCELLED


def test_cancelling_a_staged_run_withdraws_it_through_the_commit_hook(
    agent, booked, owner, eager_tasks, django_capture_on_commit_callbacks
):
    staging.run_stage(run_id=booked.pk)
    _cancel(booked, owner, django_capture_on_commit_callbacks, hooks_run=True)
    assert _state(booked) == RunState.CANCELLED
    assert agent.client.get_run(booked.agent_run_id)["state"] == "cancelled"
    assert not staging.runs_due_for_withdrawal().exists()


def test_cancelling_a_running_run_aborts_it_through_the_commit_hook_and_the_robot_stops(
    agent, booked, owner, eager_tasks, django_capture_on_commit_callbacks
):
    now_s = _stage_and_start(agent, booked)
    assert agent.client.status()["robot"]["commanded_velocity_mps"] > 0
    _cancel(booked, owner, django_capture_on_commit_callbacks, hooks_run=True)
    assert agent.client.get_run(booked.agent_run_id)["state"] == "aborted"
    agent.run_clock(now_s + TICK_S, now_s + 1.0)
    assert agent.client.status()["robot"]["commanded_velocity_mps"] == 0.0
    collection.run_collect(run_id=booked.pk)
    assert _state(booked) == RunState.INTERRUPTED
    on_agent = agent.client.get_run(booked.agent_run_id)
    assert Sample.objects.filter(run=booked).count() == on_agent["sample_count"] > 0


def test_a_staged_run_whose_withdrawal_was_lost_is_withdrawn_by_the_sweep(
    agent, booked, owner, eager_tasks, django_capture_on_commit_callbacks
):
    staging.run_stage(run_id=booked.pk)
    _cancel(booked, owner, django_capture_on_commit_callbacks, hooks_run=False)
    # The hook's task never ran: the agent would still start the run.
    assert _state(booked) == RunState.STAGED
    assert agent.client.get_run(booked.agent_run_id)["state"] == "staged"
    assert list(staging.runs_due_for_withdrawal()) == [booked]
    tasks.runs_sweep.apply()
    assert _state(booked) == RunState.CANCELLED
    assert agent.client.get_run(booked.agent_run_id)["state"] == "cancelled"
    assert not staging.runs_due_for_withdrawal().exists()


def test_a_running_run_whose_withdrawal_was_lost_is_aborted_by_the_sweep(
    agent, booked, owner, eager_tasks, django_capture_on_commit_callbacks
):
    now_s = _stage_and_start(agent, booked)
    _cancel(booked, owner, django_capture_on_commit_callbacks, hooks_run=False)
    assert agent.client.get_run(booked.agent_run_id)["state"] == "running"
    tasks.runs_sweep.apply()
    assert agent.client.get_run(booked.agent_run_id)["state"] == "aborted"
    agent.run_clock(now_s + TICK_S, now_s + 1.0)
    assert agent.client.status()["robot"]["commanded_velocity_mps"] == 0.0
    # Still running here until collected: the sweep asks for the withdrawal again meanwhile.
    assert list(staging.runs_due_for_withdrawal()) == [booked]
    collection.run_collect(run_id=booked.pk)
    assert _state(booked) == RunState.INTERRUPTED
    assert not staging.runs_due_for_withdrawal().exists()


def test_a_run_the_agent_does_not_know_fails(agent, booked):
    Run.objects.filter(pk=booked.pk).update(state=RunState.STAGED)
    collection.run_collect(run_id=booked.pk)
    assert _state(booked) == RunState.FAILED
    assert "no record" in booked.reason
