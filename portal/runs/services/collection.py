"""Collecting a run's samples from its base-station agent, and closing the run.

The database is the schedule: a periodic sweep finds runs due for collection and
:func:`run_collect` does one round, idempotently — it resumes after the last stored sample,
stores each (run, seq) once, and closes the run only when the stored count equals the
agent's. Nothing is marked complete with a gap.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import psycopg
from django.db import IntegrityError, connection, transaction
from django.db.models import Count, Max, QuerySet

from basestation.client import AgentClient, AgentError
from basestation.contract import AGENT_RUNNING, SAMPLE_FIELDS, sample_parse
from bookings.services import reservation_complete
from portal.runs.agents import agent_client_for
from portal.runs.models import Run, Sample
from portal.runs.services.transitions import run_transition
from portal.runs.states import RUN_ACTIVE_STATES, STATE_FOR_AGENT_END, Cause, RunState

logger = logging.getLogger(__name__)

SAMPLES_PAGE = 5000
_T = SAMPLE_FIELDS.index("t")


def runs_due_for_collection(*, now: datetime) -> QuerySet[Run]:
    return Run.objects.filter(state__in=RUN_ACTIVE_STATES, start_at__lte=now)


# --- Ingest ---------------------------------------------------------------------------------


def samples_ingest(*, run: Run, samples: list[dict[str, Any]]) -> int:
    """Store a page of samples from the agent; duplicates (same run and seq) are skipped.

    Returns how many rows the page held. ``run.last_seq`` only moves forward. Every value is
    checked against the contract's columns first (``ValueError`` naming the sample and
    column, nothing stored). On PostgreSQL the page goes in by ``COPY``: several times faster
    than row inserts, and still idempotent.
    """
    if not samples:
        return 0
    rows = []
    for raw in samples:
        row = list(sample_parse(raw))
        row[_T] = datetime.fromtimestamp(row[_T], tz=UTC)
        rows.append(tuple(row))
    last_seq = max(r[0] for r in rows)
    with transaction.atomic():
        if connection.vendor == "postgresql":
            _copy_samples(run.pk, rows)
        else:
            Sample.objects.bulk_create(
                [Sample(run=run, **dict(zip(SAMPLE_FIELDS, r, strict=True))) for r in rows],
                batch_size=2000,
                ignore_conflicts=True,
            )
        Run.objects.filter(pk=run.pk, last_seq__lt=last_seq).update(last_seq=last_seq)
    run.last_seq = max(run.last_seq, last_seq)
    return len(rows)


def _page_table_sql() -> str:
    """The temporary table a page is merged through: the contract's columns, with the
    model's column types (the contract test keeps model and contract in step)."""
    fields = {f.name: f for f in Sample._meta.concrete_fields}
    columns = ", ".join(f"{name} {fields[name].db_type(connection)}" for name in SAMPLE_FIELDS)
    return f"CREATE TEMPORARY TABLE IF NOT EXISTS sample_page ({columns}) ON COMMIT DELETE ROWS"


def _copy_samples(run_id: int, rows: list[tuple[Any, ...]]) -> None:
    """COPY straight into the table; if a row is already there (a repeated or overlapping
    collection), roll that back and merge through a temporary table instead."""
    columns = ", ".join(SAMPLE_FIELDS)
    table = Sample._meta.db_table
    try:
        with (
            transaction.atomic(),
            connection.cursor() as cursor,
            cursor.copy(f"COPY {table} (run_id, {columns}) FROM STDIN") as copy,
        ):
            for row in rows:
                copy.write_row((run_id, *row))
        return
    except (IntegrityError, psycopg.errors.UniqueViolation):
        # COPY goes to psycopg directly, so its error arrives unwrapped by Django. The unique
        # (run, seq) constraint saw a duplicate and the savepoint undid the whole page.
        pass
    with connection.cursor() as cursor:
        # Emptied at every commit, so one per connection serves every page.
        cursor.execute(_page_table_sql())
        with cursor.copy(f"COPY sample_page ({columns}) FROM STDIN") as copy:
            for row in rows:
                copy.write_row(row)
        # Identifiers are the contract's and the model's; the run id is a bound parameter.
        cursor.execute(
            f"INSERT INTO {table} (run_id, {columns}) SELECT %s, {columns} FROM sample_page "  # noqa: S608
            "ON CONFLICT (run_id, seq) DO NOTHING",
            [run_id],
        )


def run_sample_stats(*, run: Run) -> dict[str, int]:
    stats = Sample.objects.filter(run=run).aggregate(count=Count("pk"), last_seq=Max("seq"))
    return {"count": stats["count"] or 0, "last_seq": stats["last_seq"] or 0}


# --- Collection -----------------------------------------------------------------------------


@dataclass(frozen=True)
class AgentRunView:
    """What one look at the agent said of a run, before its samples were pulled."""

    state: str
    sample_count: int
    reason: str
    rail_length_m: float | None


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


def _close(run: Run, view: AgentRunView, final_state: RunState) -> None:
    """The agent has ended the run: verify the count and end it here the same way."""
    run_transition(
        run_id=run.pk,
        to_state=RunState.COLLECTING,
        cause=Cause.DISPATCH,
        from_states=[RunState.STAGED, RunState.RUNNING],
        reason=f"ended on the base station ({view.state})",
    )
    Run.objects.filter(pk=run.pk).update(agent_sample_count=view.sample_count)
    stored = run_sample_stats(run=run)["count"]
    if stored != view.sample_count:
        # Stays ``collecting``: the next sweep pulls again.
        logger.warning(
            "run %s: %d samples stored, base station reports %d; collecting again",
            run.pk,
            stored,
            view.sample_count,
        )
        return
    reason = f"{view.sample_count} samples collected" + (f"; {view.reason}" if view.reason else "")
    ended = run_transition(
        run_id=run.pk,
        to_state=final_state,
        cause=Cause.DISPATCH,
        from_states=[RunState.COLLECTING],
        reason=reason,
    )
    if ended and final_state == RunState.COMPLETED:
        reservation_complete(reservation_id=run.reservation_id)


def run_collect(*, run_id: int) -> None:
    """Pull new samples of an active run; once the agent has ended it, verify and close it."""
    run = Run.objects.select_related("resource").get(pk=run_id)
    if run.state not in RUN_ACTIVE_STATES:
        return
    client = agent_client_for(run.resource)
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
    final_state = STATE_FOR_AGENT_END.get(view.state)
    if final_state is not None:
        _close(run, view, final_state)
