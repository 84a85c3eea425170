"""Moving runs between the portal and their base-station agents.

The database is the schedule: a periodic sweep finds what is due and these services do one
step each, idempotently. Every step re-reads the run and does nothing if the run is already
past it, so duplicated or late tasks are harmless.
"""

from __future__ import annotations

import contextlib
import logging
import math
from datetime import datetime, timedelta
from typing import Any

from django.conf import settings
from django.db.models import QuerySet
from django.utils import timezone

from basestation.client import AgentConflict, AgentError, AgentRejected
from bookings.agents import agent_client_for
from bookings.choices import ReservationState
from bookings.models import Reservation
from portal.experiments.choices import RUN_ACTIVE_STATES, RunState
from portal.experiments.models import Run
from portal.experiments.services import run_sample_stats, run_transition, samples_ingest

logger = logging.getLogger(__name__)

SAMPLES_PAGE = 5000

# How each end state of a run on the agent ends the run here.
AGENT_END_STATES: dict[str, str] = {
    "completed": RunState.COMPLETED,
    "aborted": RunState.INTERRUPTED,
    "interrupted": RunState.INTERRUPTED,
    "cancelled": RunState.CANCELLED,
    "failed": RunState.FAILED,
}


def runs_due_for_staging(*, now: datetime) -> QuerySet[Run]:
    lead = timedelta(seconds=settings.RUN_STAGE_LEAD_S)
    return Run.objects.filter(state=RunState.SCHEDULED, start_at__lte=now + lead)


def runs_due_for_collection(*, now: datetime) -> QuerySet[Run]:
    return Run.objects.filter(state__in=RUN_ACTIVE_STATES, start_at__lte=now)


def run_agent_body(run: Run) -> dict[str, Any]:
    """What the agent is asked to run: the program, its window and the robot's limits."""
    reservation = run.reservation
    resource = run.resource
    return {
        "owner": reservation.owner.get_username(),
        "title": run.title,
        "start_at": run.start_at.isoformat(),
        "end_at": run.end_at.isoformat(),
        "segments": run.segments,
        "limits": {
            "max_velocity_mps": resource.max_velocity_mps,
            "max_accel_mps2": resource.max_accel_mps2,
        },
    }


def _load(run_id: int) -> Run:
    return Run.objects.select_related("resource", "reservation__owner").get(pk=run_id)


def run_stage(*, run_id: int, now: datetime | None = None) -> None:
    """Send a scheduled run to its agent (``PUT``, idempotent by run id) → ``staged``.

    Raises ``AgentError`` with ``retryable`` set for the caller to retry.
    """
    now = now or timezone.now()
    run = _load(run_id)
    if run.state != RunState.SCHEDULED:
        return
    if run.reservation.state != ReservationState.CONFIRMED and run.end_at > now:
        return  # awaiting approval: staged once an admin confirms it
    if run.reservation.state != ReservationState.CONFIRMED:
        run_transition(
            run_id=run.pk,
            from_states=[RunState.SCHEDULED],
            to_state=RunState.FAILED,
            reason="the reservation was not approved before it ended",
        )
        return
    if run.end_at <= now:
        run_transition(
            run_id=run.pk,
            from_states=[RunState.SCHEDULED],
            to_state=RunState.FAILED,
            reason="the base station could not be reached before the reservation ended",
        )
        return
    client = agent_client_for(run.resource)
    try:
        client.put_run(run.agent_run_id, run_agent_body(run))
    except (AgentConflict, AgentRejected) as exc:
        run_transition(
            run_id=run.pk,
            from_states=[RunState.SCHEDULED],
            to_state=RunState.FAILED,
            reason=f"the base station refused the run: {exc}",
        )
        return
    if not run_transition(
        run_id=run.pk,
        from_states=[RunState.SCHEDULED],
        to_state=RunState.STAGED,
        reason=f"staged on {run.resource.name}",
    ):
        # Cancelled while we were staging it: withdraw it again.
        run.refresh_from_db(fields=["state"])
        if run.state == RunState.CANCELLED:
            client.delete_run(run.agent_run_id)


def run_unstage(*, run_id: int) -> None:
    """Withdraw a staged run from its agent, or abort it there if it is running."""
    run = _load(run_id)
    if run.state not in (RunState.STAGED, RunState.RUNNING):
        return
    client = agent_client_for(run.resource)
    # A conflict means it had already ended there; collection records how.
    with contextlib.suppress(AgentConflict):
        client.delete_run(run.agent_run_id)
    # A staged run cancelled on the agent ends here; a running one goes on to be collected.
    run_transition(
        run_id=run.pk,
        from_states=[RunState.STAGED],
        to_state=RunState.CANCELLED,
        reason="withdrawn from the base station",
    )


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


def run_collect(*, run_id: int) -> None:
    """Pull new samples of an active run; once the agent has ended it, verify and close it."""
    run = _load(run_id)
    if run.state not in RUN_ACTIVE_STATES:
        return
    client = agent_client_for(run.resource)
    try:
        # Read the state before the samples: if it is already final, this pull gets them all.
        agent_run = client.get_run(run.agent_run_id)
    except AgentError as exc:
        if exc.status == 404:
            run_transition(
                run_id=run.pk,
                from_states=RUN_ACTIVE_STATES,
                to_state=RunState.FAILED,
                reason="the base station has no record of this run",
            )
            return
        raise
    rail_length_m = _rail_length_m(agent_run)
    if rail_length_m is not None and rail_length_m != run.rail_length_m:
        Run.objects.filter(pk=run.pk).update(rail_length_m=rail_length_m)
    agent_state = str(agent_run["state"])
    if agent_state == "running":
        run_transition(
            run_id=run.pk,
            from_states=[RunState.STAGED],
            to_state=RunState.RUNNING,
            reason="started on the base station",
        )
    after_seq = run.last_seq
    while True:
        page = client.samples(run.agent_run_id, after_seq=after_seq, limit=SAMPLES_PAGE)
        samples_ingest(run=run, samples=page["samples"])
        after_seq = max(after_seq, int(page.get("last_seq") or after_seq))
        if not page["more"] or not page["samples"]:
            break
    final_state = AGENT_END_STATES.get(agent_state)
    if final_state is None:
        return
    run_transition(
        run_id=run.pk,
        from_states=[RunState.STAGED, RunState.RUNNING],
        to_state=RunState.COLLECTING,
        reason=f"ended on the base station ({agent_state})",
    )
    expected = int(agent_run.get("sample_count") or 0)
    Run.objects.filter(pk=run.pk).update(agent_sample_count=expected)
    stats = run_sample_stats(run=run)
    if stats["count"] != expected:
        # Stays ``collecting``: the next sweep pulls again. Nothing is marked complete with a gap.
        logger.warning(
            "run %s: %d samples stored, base station reports %d; collecting again",
            run.pk,
            stats["count"],
            expected,
        )
        return
    reason = f"{expected} samples collected" + (
        f"; {agent_run['reason']}" if agent_run.get("reason") else ""
    )
    if (
        run_transition(
            run_id=run.pk, from_states=[RunState.COLLECTING], to_state=final_state, reason=reason
        )
        and final_state == RunState.COMPLETED
    ):
        Reservation.objects.filter(pk=run.reservation_id, state=ReservationState.CONFIRMED).update(
            state=ReservationState.COMPLETED
        )
