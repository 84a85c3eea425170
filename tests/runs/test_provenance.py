"""How a run was made, recorded by the portal at staging and at collection from the real
agent application (``portal/runs/provenance.py``), shown by the API and the run page."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.utils import timezone

from portal.runs.models import Run
from portal.runs.provenance import (
    PORTAL_VERSION,
    provenance_at_collection,
    run_provenance_record,
)
from portal.runs.services import collection, staging
from portal.runs.services.reservations import reservation_create
from tests.factories import ExperimentFactory

pytestmark = pytest.mark.django_db


@pytest.fixture
def booked(agent, owner, mobile):
    mobile.agent_url = agent.url
    mobile.save()
    experiment = ExperimentFactory(
        owner=owner, segments=[{"velocity_mps": 0.5, "direction": "cw", "duration_s": 2.0}]
    )
    start = timezone.now() + timedelta(minutes=2)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(seconds=6),
        experiment=experiment,
    )
    return Run.objects.get(reservation=reservation)


def test_staging_and_collection_record_how_the_run_was_made(agent, booked, api):
    staging.run_stage(run_id=booked.pk)
    booked.refresh_from_db()
    staged = booked.provenance["staged"]
    assert staged["portal_version"] == PORTAL_VERSION
    assert staged["limits"] == staging.run_agent_body(booked)["limits"]
    assert staged["agent"]["interface"] == "simple"
    assert staged["agent"]["control_hz"] == 20.0
    assert staged["firmware"] is None  # the kinematic model has no firmware
    assert "collected" not in booked.provenance

    start_s = booked.start_at.timestamp()
    agent.run_clock(start_s, start_s + 5.0)
    collection.run_collect(run_id=booked.pk)
    booked.refresh_from_db()
    assert booked.state == "completed"
    collected = booked.provenance["collected"]
    assert collected["started_at"] is not None
    assert collected["ended_at"] is not None
    assert collected["agent"] == staged["agent"]
    assert set(collected["clock_at_start"]) == {
        "synchronized",
        "offset_s",
        "max_error_s",
        "estimated_error_s",
    }
    assert collected["link"]["exchanges"] == booked.samples.count()
    assert collected["link"]["lost"] == 0

    answer = api.get(f"/api/v1/runs/{booked.pk}/").json()["provenance"]
    assert answer["format_version"] == 1
    assert answer["staged"]["limits"] == staged["limits"]
    assert answer["collected"]["link"]["exchanges"] == collected["link"]["exchanges"]
    assert answer["collected"]["clock_at_end"] == collected["clock_at_end"]


def test_a_second_record_of_the_collection_keeps_the_first(agent, booked):
    """The collector's and a sweep's collections may both meet the run still ``collecting``
    and both record it as collected (as ``collection._close`` does, ``keep_first``): the
    record of when and how it was collected is written once."""
    staging.run_stage(run_id=booked.pk)
    start_s = booked.start_at.timestamp()
    agent.run_clock(start_s, start_s + 5.0)
    collection.run_collect(run_id=booked.pk)
    booked.refresh_from_db()
    first = booked.provenance["collected"]
    later = provenance_at_collection(agent_run={}, now=timezone.now() + timedelta(seconds=1))
    run_provenance_record(run_id=booked.pk, part="collected", value=later, keep_first=True)
    booked.refresh_from_db()
    assert booked.provenance["collected"] == first
    run_provenance_record(run_id=booked.pk, part="collected", value=later)
    booked.refresh_from_db()
    assert booked.provenance["collected"] == later


def test_an_agent_that_says_nothing_of_itself_leaves_the_parts_empty():
    now = timezone.now()
    older = {"id": "run-1", "state": "completed", "sample_count": 3}
    recorded = provenance_at_collection(agent_run=older, now=now)
    assert recorded["agent"] is None
    assert recorded["firmware"] is None
    assert recorded["link"] is None
    # Garbage in an answer is dropped, not stored.
    odd = {"provenance": {"started": {"agent": {"control_hz": "fast", "rail": 7}}}}
    cleaned = provenance_at_collection(agent_run=odd, now=now)["agent"]
    assert cleaned["control_hz"] is None
    assert cleaned["rail"] is None


def test_a_runs_own_limits_are_sent_within_the_robots(booked, mobile):
    mobile.max_velocity_mps = 1.0
    mobile.max_accel_mps2 = 0.8
    mobile.save()
    booked.limits = {"max_velocity_mps": 1.5, "max_accel_mps2": 0.4}
    assert staging.run_agent_body(booked)["limits"] == {
        "max_velocity_mps": 1.0,  # the robot's is stricter now
        "max_accel_mps2": 0.4,  # the run's is stricter
    }
    booked.limits = None
    assert staging.run_agent_body(booked)["limits"]["max_accel_mps2"] == 0.8


def test_the_run_page_says_how_the_run_was_made(agent, booked, client, owner):
    staging.run_stage(run_id=booked.pk)
    client.force_login(owner)
    page = client.get(f"/runs/{booked.pk}/").content.decode()
    assert "How this run was made" in page
    assert 'id="provenance-agent"' in page
    assert "20 Hz control rate" in page
    assert "not reported by the robot" in page  # the kinematic model
    assert "recorded when the run is collected" in page
    assert f"/runs/{booked.pk}/package.zip" in page


def _booked_at(owner, mobile, hours: int) -> Run:
    start = timezone.now() + timedelta(hours=hours)
    return reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=1),
        experiment=ExperimentFactory(owner=owner),
    ).run


def test_listing_runs_reads_no_more_per_run_for_their_provenance(
    api, owner, mobile, django_assert_max_num_queries
):
    Run.objects.filter(pk=_booked_at(owner, mobile, 1).pk).update(
        provenance={"format_version": 1, "staged": {"at": "2026-11-25T10:00:00+00:00"}}
    )
    with django_assert_max_num_queries(100) as one:
        api.get("/api/v1/runs/")
    for hours in (2, 3):
        _booked_at(owner, mobile, hours)
    with django_assert_max_num_queries(100) as three:
        answer = api.get("/api/v1/runs/").json()
    assert all("provenance" in run for run in answer["results"])
    # Two more runs cost exactly their sample counts (one query each), nothing for provenance.
    assert len(three.captured_queries) == len(one.captured_queries) + 2
