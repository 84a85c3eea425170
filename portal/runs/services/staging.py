"""Moving runs onto their base-station agents, and off them again.

The database is the schedule: a periodic sweep finds what is due and these services do one
step each, idempotently. Every step re-reads the run and does nothing if the run is already
past it, so duplicated or late tasks are harmless.
"""

from __future__ import annotations

import contextlib
import logging
from datetime import datetime, timedelta
from typing import Any

from django.conf import settings
from django.db import transaction
from django.db.models import QuerySet
from django.utils import timezone

from basestation.client import AgentConflict, AgentError, AgentRejected
from bookings.choices import ReservationState
from bookings.rules import velocity_limit
from core.audit.counters import event_count
from portal.runs.agents import agent_client_for
from portal.runs.models import Run
from portal.runs.provenance import provenance_at_staging, run_provenance_record
from portal.runs.services.transitions import run_transition
from portal.runs.states import Cause, RunState

logger = logging.getLogger(__name__)


def runs_due_for_staging(*, now: datetime) -> QuerySet[Run]:
    lead = timedelta(seconds=settings.RUN_STAGE_LEAD_S)
    return Run.objects.filter(state=RunState.SCHEDULED, start_at__lte=now + lead)


def runs_due_for_withdrawal() -> QuerySet[Run]:
    """Runs on their agents whose booking was cancelled or rejected: the withdrawal queued
    with the cancellation may have been lost (a worker or broker restart), so the sweep
    queues it again until collection sees the run end."""
    return Run.objects.filter(
        state__in=[RunState.STAGED, RunState.RUNNING],
        reservation__state__in=[ReservationState.CANCELLED, ReservationState.REJECTED],
    )


def _stricter(a: float | None, b: Any) -> float | None:
    """The lower of two limits, either possibly absent (None: no limit from that side)."""
    if isinstance(b, bool) or not isinstance(b, int | float) or b <= 0:
        return a
    return float(b) if a is None else min(a, float(b))


def run_agent_body(run: Run) -> dict[str, Any]:
    """What the agent is asked to run: the program, its window and the robot's limits (the
    stricter of the resource's and those its agent reported, as booking checked them), and
    within them the run's own (``Run.limits``: a repeat asks for its original's)."""
    reservation = run.reservation
    resource = run.resource
    limit = velocity_limit(resource)
    accel = resource.max_accel_mps2
    if accel is not None and resource.agent_max_accel_mps2 is not None:
        accel = min(accel, resource.agent_max_accel_mps2)
    velocity = None if limit is None else limit.mps
    own = run.limits or {}
    return {
        "owner": reservation.owner.get_username(),
        "title": run.title,
        "start_at": run.start_at.isoformat(),
        "end_at": run.end_at.isoformat(),
        "segments": run.segments,
        "limits": {
            "max_velocity_mps": _stricter(velocity, own.get("max_velocity_mps")),
            "max_accel_mps2": _stricter(accel, own.get("max_accel_mps2")),
        },
    }


def _load(run_id: int) -> Run | None:
    """The run, or None if it is gone (its reservation deleted since the task was queued)."""
    return Run.objects.select_related("resource", "reservation__owner").filter(pk=run_id).first()


def _fail(run: Run, reason: str) -> None:
    run_transition(
        run_id=run.pk,
        to_state=RunState.FAILED,
        cause=Cause.DISPATCH,
        from_states=[RunState.SCHEDULED],
        reason=reason,
    )


def run_stage(*, run_id: int, now: datetime | None = None) -> None:
    """Send a scheduled run to its agent (``PUT``, idempotent by run id) → ``staged``.

    Raises ``AgentError`` with ``retryable`` set for the caller to retry, until
    ``RUN_START_GRACE_S`` after the run's start: an agent still out of reach then fails the
    run with the error (its owner is told). A run staged late starts late on the robot.
    """
    now = now or timezone.now()
    run = _load(run_id)
    if run is None or run.state != RunState.SCHEDULED:
        return
    if run.reservation.state in (ReservationState.CANCELLED, ReservationState.REJECTED):
        # Cancelled where the runs layer does not see it (the lease API, for a booking made
        # there and given an experiment later): the run goes with its booking.
        run_transition(
            run_id=run.pk,
            to_state=RunState.CANCELLED,
            cause=Cause.BOOKING,
            from_states=[RunState.SCHEDULED],
            reason=f"its booking was {run.reservation.get_state_display()}",
            by=run.reservation.cancelled_by,
        )
        return
    confirmed = run.reservation.state == ReservationState.CONFIRMED
    if not confirmed and run.end_at > now:
        return  # awaiting approval: staged once an admin confirms it
    if not confirmed:
        _fail(run, "the reservation was not approved before it ended")
        return
    if run.end_at <= now:
        _fail(run, "the base station could not be reached before the reservation ended")
        return
    client = agent_client_for(run.resource)
    body = run_agent_body(run)
    try:
        staged = client.put_run(run.agent_run_id, body)
    except (AgentConflict, AgentRejected) as exc:
        event_count("run_staging_failures", resource=run.resource.name, outcome="failed")
        _fail(run, f"the base station refused the run: {exc}")
        return
    except AgentError as exc:
        grace_s = settings.RUN_START_GRACE_S
        if exc.retryable and now <= run.start_at + timedelta(seconds=grace_s):
            event_count("run_staging_failures", resource=run.resource.name, outcome="retrying")
            raise
        event_count("run_staging_failures", resource=run.resource.name, outcome="failed")
        _fail(
            run,
            f"the base station could not be reached by {grace_s:g} s after the run's start: "
            f"{exc.message}",
        )
        return
    # Staged and how, together: a run is never staged here without its record.
    with transaction.atomic():
        moved = run_transition(
            run_id=run.pk,
            to_state=RunState.STAGED,
            cause=Cause.DISPATCH,
            from_states=[RunState.SCHEDULED],
            reason=f"staged on {run.resource.name}",
        )
        if moved:
            run_provenance_record(
                run_id=run.pk,
                part="staged",
                value=provenance_at_staging(agent_run=staged, limits=body["limits"], now=now),
            )
    if not moved:
        # Cancelled while we were staging it: withdraw it again.
        run.refresh_from_db(fields=["state"])
        if run.state == RunState.CANCELLED:
            client.delete_run(run.agent_run_id)


def run_unstage(*, run_id: int) -> None:
    """Withdraw a staged run from its agent, or abort it there if it is running."""
    run = _load(run_id)
    if run is None or run.state not in (RunState.STAGED, RunState.RUNNING):
        return
    client = agent_client_for(run.resource)
    # A conflict means it had already ended there; collection records how.
    with contextlib.suppress(AgentConflict):
        client.delete_run(run.agent_run_id)
    # A staged run cancelled on the agent ends here; a running one goes on to be collected.
    run_transition(
        run_id=run.pk,
        to_state=RunState.CANCELLED,
        cause=Cause.DISPATCH,
        from_states=[RunState.STAGED],
        reason="withdrawn from the base station",
    )
