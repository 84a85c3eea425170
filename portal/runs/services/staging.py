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
from django.db.models import F, Q, QuerySet
from django.utils import timezone

from basestation.client import AgentConflict, AgentError, AgentRejected
from bookings.choices import ReservationState
from bookings.models import Reservation
from bookings.rules import velocity_limit
from core.audit.counters import event_count
from portal.runs.agents import agent_client_for
from portal.runs.models import Run
from portal.runs.provenance import provenance_at_staging, run_provenance_record
from portal.runs.services.transitions import run_transition
from portal.runs.states import Cause, RunState

logger = logging.getLogger(__name__)


# A run may go to its agent only when its booking is confirmed and holds the run's window:
# the booking services move both together, so anything else means the booking changed where
# its run did not follow (a write around the services), and the robot would run outside it.
BOOKING_HOLDS_RUN = Q(
    reservation__state=ReservationState.CONFIRMED,
    reservation__start_at=F("start_at"),
    reservation__end_at=F("end_at"),
)
# Awaiting an admin's decision, in its own window: it waits (staged once confirmed).
BOOKING_AWAITS_DECISION = Q(
    reservation__state=ReservationState.REQUESTED,
    reservation__start_at=F("start_at"),
    reservation__end_at=F("end_at"),
)


def _due(now: datetime) -> QuerySet[Run]:
    lead = timedelta(seconds=settings.RUN_STAGE_LEAD_S)
    return Run.objects.filter(state=RunState.SCHEDULED, start_at__lte=now + lead)


def runs_due_for_staging(*, now: datetime) -> QuerySet[Run]:
    """Scheduled runs starting within the lead whose booking is confirmed and is their window."""
    return _due(now).filter(BOOKING_HOLDS_RUN)


def runs_held_from_staging(*, now: datetime) -> QuerySet[Run]:
    """Scheduled runs due to be staged that their booking does not hold (cancelled, rejected,
    completed, moved without them, or awaiting a decision past its end): ``run_hold`` each."""
    return (
        _due(now)
        .exclude(BOOKING_HOLDS_RUN)
        .exclude(BOOKING_AWAITS_DECISION & Q(reservation__end_at__gt=now))
    )


def staging_refusal(run: Run, reservation: Reservation, *, now: datetime) -> str | None:
    """Why ``run`` may not be handed to its agent now, or None; "" while it waits for an
    admin's decision (its booking requested, in its window, not yet over)."""
    if reservation.state in (ReservationState.CANCELLED, ReservationState.REJECTED):
        return f"its booking was {reservation.get_state_display()}"
    booked = (reservation.start_at, reservation.end_at)
    if (run.start_at, run.end_at) != booked:
        return (
            f"its booking holds {booked[0].isoformat()} to {booked[1].isoformat()}, not the "
            f"run's {run.start_at.isoformat()} to {run.end_at.isoformat()} (the booking was "
            "changed without its run)"
        )
    if reservation.state == ReservationState.REQUESTED:
        return (
            "" if reservation.end_at > now else "the reservation was not approved before it ended"
        )
    if reservation.state != ReservationState.CONFIRMED:
        return f"its booking is {reservation.get_state_display()}, not confirmed"
    return None


def run_hold(*, run_id: int, now: datetime | None = None) -> bool:
    """Keep a scheduled run its booking does not hold off its agent, and say why.

    A withdrawn booking's run is cancelled with it; any other mismatch fails the run with the
    reason (its owner is told, the log and the run's history say what was found): a person
    books it again, nobody guesses which window was meant. True if the run was held.
    """
    now = now or timezone.now()
    with transaction.atomic():
        # Reservation first, then run: the order every path that takes both locks uses.
        run = Run.objects.filter(pk=run_id, state=RunState.SCHEDULED).first()
        if run is None:
            return False
        reservation = Reservation.objects.select_for_update().get(pk=run.reservation_id)
        run = Run.objects.select_for_update().filter(pk=run_id).first()
        if run is None:
            return False
        why = staging_refusal(run, reservation, now=now)
        if not why:
            return False
        withdrawn = reservation.state in (ReservationState.CANCELLED, ReservationState.REJECTED)
        held = run_transition(
            run_id=run.pk,
            to_state=RunState.CANCELLED if withdrawn else RunState.FAILED,
            cause=Cause.BOOKING if withdrawn else Cause.DISPATCH,
            from_states=[RunState.SCHEDULED],
            reason=why if withdrawn else f"not staged: {why}",
            by=reservation.cancelled_by if withdrawn else None,
        )
    if held:
        logger.warning("run %s held from staging: %s", run_id, why)
    return held


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
    why = staging_refusal(run, run.reservation, now=now)
    if why == "":
        return  # awaiting approval: staged once an admin confirms it
    if why is not None:
        run_hold(run_id=run.pk, now=now)
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
    # Staged and how, together: a run is never staged here without its record. The claim
    # re-reads the booking under its lock: moved or cancelled while the agent was asked, the
    # run is not staged and is taken off the agent again.
    with transaction.atomic():
        reservation = Reservation.objects.select_for_update().get(pk=run.reservation_id)
        current = Run.objects.select_for_update().get(pk=run.pk)
        sent = (body["start_at"], body["end_at"])
        if staging_refusal(current, reservation, now=now) is not None or sent != (
            current.start_at.isoformat(),
            current.end_at.isoformat(),
        ):
            moved = False
        else:
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
        # Cancelled, moved or changed while we were staging it: withdraw it again, and hold it
        # if its booking no longer holds it (a run moved with its booking is staged again by
        # the next sweep, if its agent takes it).
        run.refresh_from_db(fields=["state"])
        if run.state in (RunState.CANCELLED, RunState.SCHEDULED):
            client.delete_run(run.agent_run_id)
        if run.state == RunState.SCHEDULED:
            run_hold(run_id=run.pk, now=now)


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
