"""How a run ends: the final check against the agent's count and sequence range.

The agent runs in-process behind a real HTTP server with its clock driven by hand (see
``tests/runs/conftest.py``), so each ending can be produced exactly: completed, stopped
early, samples lost on the base station, the base station out of reach past the grace, a
collection cut off half-way and resumed.
"""

from __future__ import annotations

import sqlite3
from datetime import timedelta

import pytest
from django.utils import timezone

from basestation.client import AgentError
from portal.runs.models import Run, Sample
from portal.runs.services import collection, staging
from portal.runs.services.collection import MissingRange, missing_described, samples_ingest
from portal.runs.services.reservations import reservation_create
from portal.runs.states import RunState
from tests.factories import ExperimentFactory
from tests.runs.driving import drive
from tests.sqlite import run_on_sqlite

pytestmark = pytest.mark.django_db

TICK_S = 0.05
PROGRAM_S = 4.0


@pytest.fixture
def staged(agent, owner, mobile):
    mobile.agent_url = agent.url
    mobile.save()
    experiment = ExperimentFactory(
        owner=owner,
        segments=[
            {"velocity_mps": 0.5, "direction": "cw", "duration_s": PROGRAM_S / 2},
            {"velocity_mps": 0.5, "direction": "ccw", "duration_s": PROGRAM_S / 2},
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
    run = Run.objects.get(reservation=reservation)
    staging.run_stage(run_id=run.pk)
    return run


def _agent_seqs(agent, run: Run) -> list[int]:
    return [s["seq"] for s in agent.client.iter_samples(run.agent_run_id)]


def _stored_seqs(run: Run) -> list[int]:
    return list(Sample.objects.filter(run=run).order_by("seq").values_list("seq", flat=True))


def test_a_run_the_agent_completed_with_every_sample_here_is_completed(agent, staged):
    start_s = staged.start_at.timestamp()
    agent.run_clock(start_s, start_s + PROGRAM_S + 2)
    collection.run_collect(run_id=staged.pk)
    staged.refresh_from_db()
    assert staged.state == RunState.COMPLETED
    assert staged.missing == []
    assert _stored_seqs(staged) == _agent_seqs(agent, staged)


def test_a_run_stopped_early_on_the_agent_is_interrupted_with_the_part_never_recorded(
    agent, staged, api
):
    start_s = staged.start_at.timestamp()
    agent.run_clock(start_s, start_s + 1.0)
    collection.run_collect(run_id=staged.pk)
    # The agent dies and comes back: its store marks the run it was driving interrupted.
    agent.runtime.store.mark_interrupted(now_s=start_s + 1.2, reason="agent restarted during run")
    collection.run_collect(run_id=staged.pk)
    staged.refresh_from_db()
    assert staged.state == RunState.INTERRUPTED
    stored = _stored_seqs(staged)
    assert stored == _agent_seqs(agent, staged) == list(range(1, len(stored) + 1))
    [tail] = [MissingRange(**m) for m in staged.missing]
    assert (tail.first_seq, tail.last_seq) == (stored[-1] + 1, None)
    assert tail.from_s == pytest.approx(1.0, abs=0.1)
    assert tail.to_s == pytest.approx(PROGRAM_S)
    assert "agent restarted during run" in staged.reason
    assert f"seq {stored[-1] + 1} onwards" in staged.reason
    assert missing_described(staged.missing) == [tail.describe()]
    shown = api.get(f"/api/v1/runs/{staged.pk}/").json()
    assert (shown["state"], shown["missing"]) == ("interrupted", staged.missing)


def test_a_run_stopped_early_lacks_its_tail_even_when_its_last_sample_is_past_the_reckoned_end(
    staged,
):
    """The program starts on the base station a moment after the booking's start, so its
    last samples can carry times past the end the portal reckons; stopped early there, the
    rest is still missing."""
    late_s = 0.5
    t0_s = staged.start_at.timestamp() + late_s
    rows = drive([(0.5, "cw", PROGRAM_S)])[:-2]  # stopped two samples before the end
    samples_ingest(
        run=staged,
        samples=[
            {**{k: v for k, v in r._asdict().items() if k != "t_s"}, "t": t0_s + r.t_s}
            for r in rows
        ],
    )
    program_end = staged.start_at + timedelta(seconds=PROGRAM_S)
    last_s = late_s + rows[-1].t_s
    assert last_s > PROGRAM_S
    [tail] = collection.run_missing_ranges(
        run=staged, agent_last_seq=0, program_end=program_end, stopped_early=True
    )
    assert (tail.first_seq, tail.last_seq) == (rows[-1].seq + 1, None)
    assert tail.from_s == pytest.approx(last_s, abs=0.01)
    assert tail.to_s is None
    # Out of reach (no word from the base station): a last sample past the end is the end.
    assert (
        collection.run_missing_ranges(run=staged, agent_last_seq=0, program_end=program_end) == []
    )


def test_samples_the_agent_lost_make_the_run_interrupted_with_their_range(agent, staged):
    start_s = staged.start_at.timestamp()
    agent.run_clock(start_s, start_s + PROGRAM_S + 2)
    # Samples 10 to 14 lost on the base station (its disk, say) before they were collected.
    with sqlite3.connect(agent.runtime.store.path) as db:
        db.execute(
            "DELETE FROM samples WHERE run_id = ? AND seq BETWEEN 10 AND 14",
            (staged.agent_run_id,),
        )
    collection.run_collect(run_id=staged.pk)
    staged.refresh_from_db()
    assert staged.state == RunState.INTERRUPTED
    assert _stored_seqs(staged) == _agent_seqs(agent, staged)
    [gap] = [MissingRange(**m) for m in staged.missing]
    assert (gap.first_seq, gap.last_seq) == (10, 14)
    assert gap.from_s is not None
    assert gap.to_s is not None
    assert gap.from_s < gap.to_s
    assert "seq 10–14" in staged.reason


def test_a_collection_cut_off_half_way_resumes_after_the_last_stored_sample(
    agent, staged, monkeypatch
):
    start_s = staged.start_at.timestamp()
    agent.run_clock(start_s, start_s + PROGRAM_S + 2)
    monkeypatch.setattr(collection, "SAMPLES_PAGE", 20)
    real_samples = agent.client.__class__.samples
    pages = []

    def dies_after_two_pages(self, *args, **kwargs):
        if len(pages) == 2:
            raise AgentError("connection reset", retryable=True, status=None)
        pages.append(args)
        return real_samples(self, *args, **kwargs)

    monkeypatch.setattr(agent.client.__class__, "samples", dies_after_two_pages)
    with pytest.raises(AgentError):
        collection.run_collect(run_id=staged.pk)
    assert _stored_seqs(staged) == list(range(1, 41))
    monkeypatch.setattr(agent.client.__class__, "samples", real_samples)
    collection.run_collect(run_id=staged.pk)
    collection.run_collect(run_id=staged.pk)  # and again: nothing twice
    staged.refresh_from_db()
    assert staged.state == RunState.COMPLETED
    assert _stored_seqs(staged) == _agent_seqs(agent, staged)


def test_an_agent_out_of_reach_past_the_grace_ends_the_run_with_what_was_collected(
    agent, staged, mobile, settings
):
    start_s = staged.start_at.timestamp()
    agent.run_clock(start_s, start_s + 1.0)
    collection.run_collect(run_id=staged.pk)
    stored = _stored_seqs(staged)
    assert stored
    mobile.agent_url = "http://127.0.0.1:9"  # nothing listens: the base station is gone
    mobile.save()
    within = staged.end_at + timedelta(seconds=settings.RUN_COLLECT_GRACE_S - 1)
    with pytest.raises(AgentError):
        collection.run_collect(run_id=staged.pk, now=within)
    assert Run.objects.get(pk=staged.pk).state == RunState.RUNNING
    past = staged.end_at + timedelta(seconds=settings.RUN_COLLECT_GRACE_S + 1)
    collection.run_collect(run_id=staged.pk, now=past)
    staged.refresh_from_db()
    assert staged.state == RunState.INTERRUPTED
    assert "could not be reached" in staged.reason
    assert f"up to seq {stored[-1]}" in staged.reason
    [tail] = [MissingRange(**m) for m in staged.missing]
    assert (tail.first_seq, tail.last_seq, tail.to_s) == (stored[-1] + 1, None, PROGRAM_S)


def test_an_agent_out_of_reach_from_the_start_past_the_grace_fails_the_run(
    staged, mobile, settings
):
    mobile.agent_url = "http://127.0.0.1:9"
    mobile.save()
    past = staged.end_at + timedelta(seconds=settings.RUN_COLLECT_GRACE_S + 1)
    collection.run_collect(run_id=staged.pk, now=past)
    staged.refresh_from_db()
    assert staged.state == RunState.FAILED
    assert "no samples collected" in staged.reason


def test_a_run_the_agent_failed_fails_here_with_its_reason(agent, staged):
    # A flat battery: the agent refuses to start the run when it is due.
    agent.runtime.robot._charge_v = 45.0
    start_s = staged.start_at.timestamp()
    agent.run_clock(start_s - 3.0, start_s + 1.0)
    collection.run_collect(run_id=staged.pk)
    staged.refresh_from_db()
    assert staged.state == RunState.FAILED
    on_agent = agent.client.get_run(staged.agent_run_id)
    assert on_agent["state"] == "failed"
    assert on_agent["reason"] in staged.reason


def test_a_staging_attempt_past_the_start_grace_fails_the_run_and_says_why(
    staged, mobile, settings
):
    settings.RUN_START_GRACE_S = 3.0  # well inside the 10 s booking
    scheduled = Run.objects.filter(pk=staged.pk)
    scheduled.update(state=RunState.SCHEDULED)
    mobile.agent_url = "http://127.0.0.1:9"
    mobile.save()
    within = staged.start_at + timedelta(seconds=settings.RUN_START_GRACE_S - 1)
    with pytest.raises(AgentError):
        staging.run_stage(run_id=staged.pk, now=within)
    assert scheduled.get().state == RunState.SCHEDULED
    staging.run_stage(
        run_id=staged.pk, now=staged.start_at + timedelta(seconds=settings.RUN_START_GRACE_S + 1)
    )
    staged.refresh_from_db()
    assert staged.state == RunState.FAILED
    assert "could not be reached" in staged.reason
    assert "ConnectionError" in staged.reason


SQLITE_SCRIPT = r"""
from datetime import timedelta
from django.utils import timezone
from bookings.models import Resource
from core.accounts.models import User
from portal.experiments.models import Experiment
from portal.runs.services.reservations import reservation_create
from portal.runs.services.collection import samples_ingest, run_missing_ranges
from tests.runs.driving import drive, segments

program = [(0.5, "cw", 4.0)]
alice = User.objects.create_user("alice")
robot = Resource.objects.create(name="mobile-1", kind="mobile", agent_url="http://127.0.0.1:1",
                                max_velocity_mps=2.0, max_accel_mps2=1.0)
experiment = Experiment.objects.create(owner=alice, title="gaps", segments=segments(program))
start = timezone.now() + timedelta(hours=1)
run = reservation_create(owner=alice, resource=robot, start_at=start,
                     end_at=start + timedelta(seconds=10), experiment=experiment).run
rows = drive(program, skip=frozenset({1, 2, 10, 11, 12}))
samples_ingest(run=run, samples=[{**{k: v for k, v in r._asdict().items() if k != "t_s"},
                                  "t": start.timestamp() + r.t_s} for r in rows])
for m in run_missing_ranges(run=run, agent_last_seq=85, program_end=None):
    print("range", m.first_seq, m.last_seq)
"""


def test_missing_ranges_are_found_the_same_way_on_sqlite(tmp_path):
    """``make run``'s database: the window query that finds the gaps works there too."""
    lines = run_on_sqlite(SQLITE_SCRIPT, tmp_path)
    assert [line for line in lines if line.startswith("range")] == [
        "range 1 2",
        "range 10 12",
        "range 81 85",
    ]
