"""Collecting a run's samples from its base-station agent, and closing the run.

The database is the schedule: a periodic sweep finds runs due for collection and
:func:`run_collect` does one round, idempotently — it resumes after the last stored sample
(so a worker killed half-way loses nothing: the next round starts where the database says),
stores each (run, seq) once, and publishes what arrived for the live pages.

Once the agent has ended the run, a final check compares what is stored with the agent's
count and sequence range and decides how the run ends here:

- ``completed``: the agent completed it and every sequence number from 1 to its last is
  stored — nothing is marked complete with a gap;
- ``interrupted``: the agent stopped it early (e-stop, low battery, a restart of the agent),
  or sequence numbers are missing; :class:`MissingRange` lists them, and the part of the
  program never recorded;
- ``failed``: the agent failed it, has no record of it, or stayed out of reach for
  ``RUN_COLLECT_GRACE_S`` after the run's end without a sample collected (with the reason).

While the stored count is short of the agent's, the run stays ``collecting`` and the next
sweeps pull again, up to the same grace.

The sweep alone would leave a sample on the base station for up to one sweep interval. So
the collector (``portal/runs/collector.py``, a process of its own) follows each staged or
running run with :func:`run_follow_page`: a long-poll on the agent that answers as soon as
the next samples are durable there, stored here through the same :func:`samples_ingest`.
The sweep stays the safety net (it resumes after the last stored sample whoever stored it)
and the final check stays :func:`run_collect`'s.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

import psycopg
from django.conf import settings
from django.db import IntegrityError, transaction
from django.db.models import Count, F, Max, Min, QuerySet, Window
from django.db.models.functions import Lead
from django.urls import reverse
from django.utils import timezone

from basestation.client import AgentClient, AgentError
from basestation.contract import (
    AGENT_ACTIVE_STATES,
    AGENT_RUNNING,
    SAMPLE_FIELDS,
    samples_parse,
)
from bookings.models import Reservation
from bookings.services import reservation_complete
from core import sql
from core.events.services import event_record
from core.live import samples_announced, samples_publish, samples_publish_on_commit
from portal.runs import queries
from portal.runs.agents import agent_client_for
from portal.runs.models import RUNS, Run, Sample
from portal.runs.provenance import provenance_at_collection, run_provenance_record
from portal.runs.services.transitions import run_transition
from portal.runs.states import RUN_ACTIVE_STATES, STATE_FOR_AGENT_END, Cause, RunState

logger = logging.getLogger(__name__)

SAMPLES_PAGE = 5000
_T = SAMPLE_FIELDS.index("t")
_SEQ = SAMPLE_FIELDS.index("seq")


# The collector follows a run from this long before its start: its long-poll is already
# waiting when the first sample is stored.
FOLLOW_LEAD_S = 5.0
RUN_FOLLOWED_STATES = (RunState.STAGED, RunState.RUNNING)


def runs_due_for_collection(*, now: datetime) -> QuerySet[Run]:
    return Run.objects.filter(state__in=RUN_ACTIVE_STATES, start_at__lte=now)


def runs_to_follow(*, now: datetime) -> QuerySet[Run]:
    """Runs the collector follows live: staged or running, starting soon or started."""
    return Run.objects.filter(
        state__in=RUN_FOLLOWED_STATES, start_at__lte=now + timedelta(seconds=FOLLOW_LEAD_S)
    )


# --- Ingest ---------------------------------------------------------------------------------


def samples_ingest(*, run: Run, samples: list[dict[str, Any]]) -> int:
    """Store a page of samples from the agent; duplicates (same run and seq) are skipped.

    Returns how many of the page's samples were new here. ``run.last_seq`` only moves
    forward. Every value is checked against the contract's columns first (``ValueError``
    naming the sample and column, nothing stored). On PostgreSQL the page goes in by
    ``COPY``: several times faster than row inserts, and still idempotent.

    The live pages hear of exactly the samples this call stored — one ``samples`` event per
    run of consecutive new sequence numbers, after the commit — so when the collector and a
    sweep pull the same samples at once, every sample is announced once.
    """
    if not samples:
        return 0
    # Checked a column at a time (as each sample alone would be): per-value checks cost
    # as much as the COPY itself. Times stay seconds since the epoch until stored.
    rows = samples_parse(samples)
    last_seq = max(r[_SEQ] for r in rows)
    timed = [_with_datetime(r) for r in rows]
    with transaction.atomic():
        if sql.is_postgresql():
            stored = _copy_samples(run.pk, timed)
        else:
            stored = _insert_samples(run, timed)
        moved = Run.objects.filter(pk=run.pk, last_seq__lt=last_seq).update(last_seq=last_seq)
        if stored and not moved:  # samples below the last one (a gap filled): counts changed
            RUNS.changed()
        t_by_seq = {r[_SEQ]: r[_T] for r in rows}
        for first, last in _consecutive(stored):
            times_s = [t_by_seq[seq] for seq in range(first, last + 1)]
            samples_publish_on_commit(run.pk, run.created_at, first, times_s)
    run.last_seq = max(run.last_seq, last_seq)
    return len(stored)


def _with_datetime(row: tuple[Any, ...]) -> tuple[Any, ...]:
    return (*row[:_T], datetime.fromtimestamp(row[_T], tz=UTC), *row[_T + 1 :])


def samples_announce_missed(*, run: Run) -> int:
    """Announce the run's stored samples that never were (their publisher was killed between
    its commit and its announcement); how many. Called when the collector takes a run up.
    Nothing when the bus keeps no marks (the file transport) or cannot be reached."""
    announced = samples_announced(run.pk, run.created_at)
    if announced is None:
        return 0
    missed = [
        (seq, t)
        for seq, t in Sample.objects.filter(run=run).order_by("seq").values_list("seq", "t")
        if not announced(seq)
    ]
    t_by_seq = dict(missed)
    for first, last in _consecutive(list(t_by_seq)):
        times_s = [t_by_seq[seq].timestamp() for seq in range(first, last + 1)]
        samples_publish(run.pk, run.created_at, first, times_s)
    if missed:
        logger.info("run %s: %d stored samples announced late", run.pk, len(missed))
    return len(missed)


def _consecutive(seqs: list[int]) -> list[tuple[int, int]]:
    """Sorted sequence numbers as (first, last) runs of consecutive ones."""
    ranges: list[tuple[int, int]] = []
    for seq in sorted(seqs):
        if ranges and seq == ranges[-1][1] + 1:
            ranges[-1] = (ranges[-1][0], seq)
        else:
            ranges.append((seq, seq))
    return ranges


def _insert_samples(run: Run, rows: list[tuple[Any, ...]]) -> list[int]:
    """Row inserts (SQLite), skipping sequence numbers already stored; the new ones.

    The settings open SQLite transactions ``IMMEDIATE``: what this reads stays true until
    the insert commits.
    """
    seqs = [r[0] for r in rows]
    present = set(
        Sample.objects.filter(run=run, seq__gte=min(seqs), seq__lte=max(seqs)).values_list(
            "seq", flat=True
        )
    )
    fresh = [r for r in rows if r[0] not in present]
    Sample.objects.bulk_create(
        [Sample(run=run, **dict(zip(SAMPLE_FIELDS, r, strict=True))) for r in fresh],
        batch_size=2000,
        ignore_conflicts=True,
    )
    return [r[0] for r in fresh]


def _overlaps_stored(run_id: int, rows: list[tuple[Any, ...]]) -> bool:
    """Whether any sequence number in the page's range is stored already: one index probe."""
    seqs = [row[_SEQ] for row in rows]
    return Sample.objects.filter(run_id=run_id, seq__gte=min(seqs), seq__lte=max(seqs)).exists()


def _copy_samples(run_id: int, rows: list[tuple[Any, ...]]) -> list[int]:
    """COPY straight into the table; if a row is already there (a repeated or overlapping
    collection), merge through a temporary table instead. Returns the sequence numbers that
    were new."""
    # A page sent again goes straight to the merge, not through a whole COPY rolled back.
    if not _overlaps_stored(run_id, rows):
        try:
            with transaction.atomic():
                queries.samples_copy(run_id, rows)
            return [row[_SEQ] for row in rows]
        except (IntegrityError, psycopg.errors.UniqueViolation):
            # Another collection stored some of them meanwhile. COPY goes to psycopg
            # directly, so its error arrives unwrapped by Django; the savepoint undid the
            # whole page.
            pass
    return queries.samples_merge(run_id, rows)


def run_sample_stats(*, run: Run) -> dict[str, int]:
    stats = Sample.objects.filter(run=run).aggregate(count=Count("pk"), last_seq=Max("seq"))
    return {"count": stats["count"] or 0, "last_seq": stats["last_seq"] or 0}


# --- What is missing ------------------------------------------------------------------------

MAX_MISSING_RANGES = 100


@dataclass(frozen=True)
class MissingRange:
    """Sequence numbers a run lacks, and the time around them (seconds since ``start_at``).

    ``last_seq`` None: everything after ``first_seq - 1`` — the part of the program the base
    station never recorded, ``from_s`` to ``to_s``. ``from_s`` or ``to_s`` is None where no
    stored sample bounds the range.
    """

    first_seq: int
    last_seq: int | None
    from_s: float | None
    to_s: float | None

    def describe(self) -> str:
        seqs = (
            f"seq {self.first_seq} onwards"
            if self.last_seq is None
            else f"seq {self.first_seq}"
            + (f"–{self.last_seq}" if self.last_seq != self.first_seq else "")
        )
        if self.from_s is None and self.to_s is None:
            return seqs
        since = "the start" if self.from_s is None else f"{self.from_s:.1f} s"
        until = "" if self.to_s is None else f" to {self.to_s:.1f} s"
        return f"{seqs} (from {since}{until})"


def missing_described(missing: list[dict[str, Any]]) -> list[str]:
    """A run's stored ``missing`` ranges in words, for its page."""
    described = []
    for item in missing:
        try:
            described.append(MissingRange(**item).describe())
        except TypeError:
            logger.warning("unreadable missing range %r", item)
    return described


def _since_start_s(run: Run, at: datetime | None) -> float | None:
    return None if at is None else round((at - run.start_at).total_seconds(), 2)


def run_missing_ranges(
    *,
    run: Run,
    agent_last_seq: int,
    program_end: datetime | None,
    stopped_early: bool = False,
) -> list[MissingRange]:
    """What the run lacks among sequence numbers 1 to ``agent_last_seq`` (the base station's
    last), and — with ``program_end`` — after its last sample up to that instant.

    ``stopped_early``: the base station said the program did not finish, so what follows its
    last sample is missing even when that sample's time is past ``program_end`` (the portal
    reckons the end from the booking's start; the program started a moment later there).
    """
    samples = Sample.objects.filter(run=run)
    bounds = samples.aggregate(first=Min("seq"), last=Max("seq"))
    first, last = bounds["first"], bounds["last"]
    ranges: list[MissingRange] = []
    if first is None:
        if agent_last_seq > 0 or program_end is not None:
            end_s = _since_start_s(run, program_end) if program_end is not None else None
            ranges.append(MissingRange(1, agent_last_seq or None, 0.0, end_s))
        return ranges
    times = dict(samples.filter(seq__in=[first, last]).values_list("seq", "t"))
    if first > 1:
        ranges.append(MissingRange(1, first - 1, None, _since_start_s(run, times[first])))
    gaps = (
        samples.annotate(
            next_seq=Window(Lead("seq"), order_by=F("seq").asc()),
            next_t=Window(Lead("t"), order_by=F("seq").asc()),
        )
        .filter(next_seq__gt=F("seq") + 1)
        .order_by("seq")
        .values_list("seq", "t", "next_seq", "next_t")
    )
    for seq, t, next_seq, next_t in gaps[:MAX_MISSING_RANGES]:
        ranges.append(
            MissingRange(seq + 1, next_seq - 1, _since_start_s(run, t), _since_start_s(run, next_t))
        )
    if agent_last_seq > last:
        ranges.append(
            MissingRange(last + 1, agent_last_seq, _since_start_s(run, times[last]), None)
        )
    elif program_end is not None and (stopped_early or times[last] < program_end):
        to_s = _since_start_s(run, program_end) if times[last] < program_end else None
        ranges.append(MissingRange(last + 1, None, _since_start_s(run, times[last]), to_s))
    return ranges[:MAX_MISSING_RANGES]


def _program_end(run: Run) -> datetime:
    """When the program would have finished: its segments end, at most the booking's end."""
    return min(run.start_at + timedelta(seconds=run.duration_s), run.end_at)


# --- Collection -----------------------------------------------------------------------------


@dataclass(frozen=True)
class AgentRunView:
    """What one look at the agent said of a run, before its samples were pulled."""

    state: str
    sample_count: int
    reason: str
    rail_length_m: float | None
    last_seq: int = 0
    # The agent's answer as it came (its ``provenance`` is recorded when the run closes).
    raw: dict[str, Any] | None = None


def _rail_length_m(agent_run: dict[str, Any]) -> float | None:
    """The rail length the agent reports with a run, if it is a usable one."""
    value = agent_run.get("rail_length_m")
    if value is None:
        return None  # an agent from before it reported one: laps and passes are not shown
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not (math.isfinite(value) and value > 0)
    ):
        logger.warning("run %s: ignoring the agent's rail length %r", agent_run.get("id"), value)
        return None
    return float(value)


def _look(run: Run, client: AgentClient) -> AgentRunView | None:
    """The agent's view of the run; None (and the run failed) if the agent has no record."""
    try:
        agent_run = client.get_run(run.agent_run_id)
    except AgentError as exc:
        if exc.status == 404:
            run_transition(
                run_id=run.pk,
                to_state=RunState.FAILED,
                cause=Cause.DISPATCH,
                from_states=RUN_ACTIVE_STATES,
                reason="the base station has no record of this run",
            )
            return None
        raise
    return AgentRunView(
        state=str(agent_run["state"]),
        sample_count=int(agent_run.get("sample_count") or 0),
        reason=str(agent_run.get("reason") or ""),
        rail_length_m=_rail_length_m(agent_run),
        last_seq=int(agent_run.get("last_seq") or 0),
        raw=agent_run,
    )


def _pull(run: Run, client: AgentClient) -> None:
    """Every sample the agent holds after the last one stored here, page by page."""
    after_seq = run.last_seq
    while True:
        page = client.samples(run.agent_run_id, after_seq=after_seq, limit=SAMPLES_PAGE)
        samples_ingest(run=run, samples=page["samples"])
        after_seq = max(after_seq, int(page.get("last_seq") or after_seq))
        if not page["more"] or not page["samples"]:
            return


@dataclass(frozen=True)
class FollowedPage:
    """What one long-poll brought: how many samples were new here, and the agent's state."""

    stored: int
    agent_state: str
    more: bool

    @property
    def agent_active(self) -> bool:
        """The run may still record samples on the agent (staged or running)."""
        return self.agent_state in AGENT_ACTIVE_STATES


def run_follow_page(*, run: Run, client: AgentClient, wait_s: int) -> FollowedPage:
    """Wait (up to ``wait_s``) for the samples the agent stores after the last one stored
    here, and store them (announced on the live bus at once).

    Resumes after ``run.last_seq`` as the database has it, so the sweep and the collector,
    pulling side by side, each store only what the other has not. Marks the run running
    when the agent says it started. Raises ``AgentError`` (the agent's 404 included: the
    run may not be staged there yet; only the sweep decides a run failed).
    """
    page = client.samples(
        run.agent_run_id, after_seq=run.last_seq, limit=SAMPLES_PAGE, wait_s=wait_s
    )
    stored = samples_ingest(run=run, samples=page["samples"])
    agent_state = str(page["state"])
    if agent_state == AGENT_RUNNING and run.state == RunState.STAGED:
        run_transition(
            run_id=run.pk,
            to_state=RunState.RUNNING,
            cause=Cause.DISPATCH,
            from_states=[RunState.STAGED],
            reason="started on the base station",
        )
        run.state = RunState.RUNNING
    return FollowedPage(stored=stored, agent_state=agent_state, more=bool(page["more"]))


def _past_grace(run: Run, now: datetime) -> bool:
    return now > run.end_at + timedelta(seconds=settings.RUN_COLLECT_GRACE_S)


def _data_ready_event(run: Run, state: RunState, missing: list[MissingRange]) -> None:
    """``run.data_ready`` for a run that ended with samples, in its ending's transaction: a
    script that waits for it fetches them at once, complete or with the gaps counted."""
    samples = run_sample_stats(run=run)["count"]
    if not samples:
        return
    event_record(
        subject=f"run:{run.pk}",
        type="run.data_ready",
        owner_id=Reservation.objects.values_list("owner_id", flat=True).get(pk=run.reservation_id),
        payload={
            "run": run.pk,
            "reservation": run.reservation_id,
            "resource": run.resource.name,
            "state": str(state),
            "samples": samples,
            "missing": len(missing),
            "files": {
                "csv": reverse("api-run-samples-csv", kwargs={"pk": run.pk}),
                "json": reverse("api-run-samples-json", kwargs={"pk": run.pk}),
                "analysis": reverse("api-run-analysis", kwargs={"pk": run.pk}),
            },
        },
    )


def _end(run: Run, to_state: RunState, reason: str, missing: list[MissingRange]) -> bool:
    """Record what is missing and end a collecting run; False if it had ended already."""
    with transaction.atomic():
        ended = run_transition(
            run_id=run.pk,
            to_state=to_state,
            cause=Cause.DISPATCH,
            from_states=[RunState.COLLECTING],
            reason=reason,
        )
        if ended:
            Run.objects.filter(pk=run.pk).update(missing=[asdict(m) for m in missing])
            _data_ready_event(run, to_state, missing)
    if ended and to_state == RunState.COMPLETED:
        reservation_complete(reservation_id=run.reservation_id)
    return ended


def _missing_text(missing: list[MissingRange]) -> str:
    shown = "; ".join(m.describe() for m in missing[:5])
    return f"missing {shown}" + (" …" if len(missing) > 5 else "")


def _close(run: Run, view: AgentRunView, final_state: RunState, now: datetime) -> None:
    """The agent has ended the run: check what is stored against it and end it here."""
    moved = run_transition(
        run_id=run.pk,
        to_state=RunState.COLLECTING,
        cause=Cause.DISPATCH,
        from_states=[RunState.STAGED, RunState.RUNNING],
        reason=f"ended on the base station ({view.state})",
    )
    if not moved and not Run.objects.filter(pk=run.pk, state=RunState.COLLECTING).exists():
        # Ended meanwhile by another collection (the collector's and a sweep's overlap): its
        # record of the run as collected stands; a second one would rewrite its time.
        return
    Run.objects.filter(pk=run.pk).update(agent_sample_count=view.sample_count)
    if view.raw is not None:
        run_provenance_record(
            run_id=run.pk,
            part="collected",
            value=provenance_at_collection(agent_run=view.raw, now=now),
            keep_first=True,
        )
    stored = run_sample_stats(run=run)["count"]
    if stored != view.sample_count and not _past_grace(run, now):
        # Stays ``collecting``: the next sweep looks and pulls again.
        logger.warning(
            "run %s: %d samples stored, base station reports %d; collecting again",
            run.pk,
            stored,
            view.sample_count,
        )
        return
    agent_said = f"; {view.reason}" if view.reason else ""
    if final_state in (RunState.FAILED, RunState.CANCELLED):
        missing = run_missing_ranges(run=run, agent_last_seq=view.last_seq, program_end=None)
        _end(run, final_state, f"{view.state} on the base station{agent_said}", missing)
        return
    # Stopped early on the base station: the rest of the program was never recorded.
    early = final_state == RunState.INTERRUPTED
    missing = run_missing_ranges(
        run=run,
        agent_last_seq=view.last_seq,
        program_end=_program_end(run) if early else None,
        stopped_early=early,
    )
    collected = f"{stored} samples collected"
    if not early and not missing and stored == view.sample_count:
        _end(run, RunState.COMPLETED, collected + agent_said, [])
        return
    why = f"{view.state} on the base station{agent_said}" if early else "samples are missing"
    _end(run, RunState.INTERRUPTED, f"{why}; {collected}; {_missing_text(missing)}", missing)


def _close_unreachable(run: Run, error: AgentError) -> None:
    """The agent stayed out of reach past the grace after the run's end: end the run with
    what was collected, saying so."""
    run_transition(
        run_id=run.pk,
        to_state=RunState.COLLECTING,
        cause=Cause.DISPATCH,
        from_states=[RunState.STAGED, RunState.RUNNING],
        reason="the base station is out of reach after the run's end",
    )
    stored = run_sample_stats(run=run)
    why = (
        f"the base station could not be reached for {settings.RUN_COLLECT_GRACE_S:g} s after "
        f"the run's end ({error.message})"
    )
    if stored["count"] == 0:
        _end(run, RunState.FAILED, f"{why}; no samples collected", [])
        return
    missing = run_missing_ranges(run=run, agent_last_seq=0, program_end=_program_end(run))
    _end(
        run,
        RunState.INTERRUPTED,
        f"{why}; {stored['count']} samples collected, up to seq {stored['last_seq']}; "
        + _missing_text(missing),
        missing,
    )


def run_collect(*, run_id: int, now: datetime | None = None) -> None:
    """Pull new samples of an active run; once the agent has ended it, check and close it.

    Raises ``AgentError`` while the agent cannot be reached, until ``RUN_COLLECT_GRACE_S``
    after the run's end; then the run ends with what was collected.
    """
    now = now or timezone.now()
    run = Run.objects.select_related("resource").filter(pk=run_id).first()
    if run is None or run.state not in RUN_ACTIVE_STATES:
        return
    client = agent_client_for(run.resource)
    try:
        # Look before pulling: if the run has already ended there, this pull gets every sample.
        view = _look(run, client)
        if view is None:
            return
        if view.rail_length_m is not None and view.rail_length_m != run.rail_length_m:
            Run.objects.filter(pk=run.pk).update(rail_length_m=view.rail_length_m)
        if view.state == AGENT_RUNNING:
            run_transition(
                run_id=run.pk,
                to_state=RunState.RUNNING,
                cause=Cause.DISPATCH,
                from_states=[RunState.STAGED],
                reason="started on the base station",
            )
        _pull(run, client)
    except AgentError as exc:
        if _past_grace(run, now):
            _close_unreachable(run, exc)
            return
        raise
    final_state = STATE_FOR_AGENT_END.get(view.state)
    if final_state is not None:
        _close(run, view, final_state, now)
