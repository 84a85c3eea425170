"""The only way a run comes to be or changes state (the table is ``portal/runs/states.py``)."""

from __future__ import annotations

import logging
from collections.abc import Iterable

from django.db import transaction
from django.utils import timezone

from bookings.models import Reservation, Resource
from core.accounts.models import User
from core.audit.services import audit_record
from core.errors import Conflict, InvalidInput, NotAllowed
from core.events.services import event_record
from portal.experiments.models import Experiment
from portal.runs.models import Run, RunEvent
from portal.runs.states import Cause, RunState, allowed, sources

logger = logging.getLogger(__name__)


class TransitionNotAllowed(ValueError):
    """A change of state the table does not allow for this cause: a programming error."""


def _run_event(
    *,
    run_id: int,
    reservation_id: int,
    owner_id: int,
    resource: str,
    from_state: str,
    to_state: str,
    reason: str,
    cause: str,
) -> None:
    """The run's new state as an event for its owner (``core.events``), in the transition's
    transaction, beside its ``RunEvent`` (the run's own history, shown on its page)."""
    event_record(
        subject=f"run:{run_id}",
        type=f"run.{to_state}",
        owner_id=owner_id,
        payload={
            "run": run_id,
            "reservation": reservation_id,
            "resource": resource,
            "state": str(to_state),
            "from_state": str(from_state) or None,
            "reason": reason,
            "cause": str(cause),
        },
    )


def run_create(
    *,
    reservation: Reservation,
    resource: Resource,
    experiment: Experiment,
    by: User | None,
    repeat_of: Run | None = None,
) -> Run:
    """The run of ``experiment`` on ``resource`` in a just-made reservation (``scheduled``).

    The program is copied: editing the experiment later never changes what is sent. A run
    that repeats another (``repeat_of``) copies that run's program, title and limits instead:
    what was run, not what the experiment says now.
    """
    run = Run(
        reservation=reservation,
        resource=resource,
        experiment=experiment,
        title=experiment.title if repeat_of is None else repeat_of.title,
        segments=experiment.segments if repeat_of is None else repeat_of.segments,
        start_at=reservation.start_at,
        end_at=reservation.end_at,
        state=RunState.SCHEDULED,
        repeat_of=repeat_of,
        limits=None if repeat_of is None else run_limits_as_made(repeat_of),
    )
    # The fields' own checks (the program's segments); what the database holds itself (the
    # related rows, which are instances read a moment ago, and the end after the start,
    # copied from the reservation that has just passed it) is left to the insert: checking
    # it here was seven statements of a booking's twenty-five.
    run.full_clean(
        exclude=["reservation", "resource", "experiment", "repeat_of"], validate_constraints=False
    )
    run.save()
    RunEvent.objects.create(
        run=run,
        from_state="",
        to_state=RunState.SCHEDULED,
        reason="booked",
        cause=Cause.BOOKING,
        by=by,
    )
    _run_event(
        run_id=run.pk,
        reservation_id=reservation.pk,
        owner_id=reservation.owner_id,
        resource=resource.name,
        from_state="",
        to_state=RunState.SCHEDULED,
        reason="booked",
        cause=Cause.BOOKING,
    )
    return run


def run_limits_as_made(run: Run) -> dict[str, float | None] | None:
    """The limits ``run`` was staged with (its provenance), else those it asked for."""
    staged = (run.provenance or {}).get("staged")
    limits = staged.get("limits") if isinstance(staged, dict) else None
    if isinstance(limits, dict):
        return {
            "max_velocity_mps": limits.get("max_velocity_mps"),
            "max_accel_mps2": limits.get("max_accel_mps2"),
        }
    return run.limits


def _states_left(
    to_state: RunState, cause: Cause, from_states: Iterable[RunState] | None
) -> tuple[str, ...]:
    """The states ``run_transition`` may move a run out of: ``from_states``, each allowed by
    the table for ``cause``, or every state the table lets ``cause`` leave for ``to_state``."""
    if from_states is None:
        return sources(to_state, cause)
    wanted = tuple(str(s) for s in from_states)
    refused = [s for s in wanted if not allowed(s, to_state, cause)]
    if refused:
        raise TransitionNotAllowed(
            f"{cause} may not move a run from {', '.join(refused)} to {to_state}"
        )
    return wanted


def run_transition(
    *,
    run_id: int,
    to_state: RunState,
    cause: Cause,
    reason: str = "",
    from_states: Iterable[RunState] | None = None,
    by: User | None = None,
) -> bool:
    """Move a run to ``to_state`` if it is in one of ``from_states``; False if it was not.

    ``from_states`` defaults to every state ``cause`` may leave for ``to_state``; naming a
    state the table does not allow raises :class:`TransitionNotAllowed`. A compare-and-set
    under a row lock, so two workers racing on the same run change it once, and a task that
    finds the run already past its step does nothing.
    """
    wanted = _states_left(to_state, cause, from_states)
    with transaction.atomic():
        found = (
            Run.objects.select_for_update(of=("self",))
            .filter(pk=run_id, state__in=wanted)
            .values_list("state", "reservation_id", "reservation__owner_id", "resource__name")
            .first()
        )
        if found is None:
            return False
        current, reservation_id, owner_id, resource = found
        Run.objects.filter(pk=run_id).update(
            state=to_state, reason=reason, updated_at=timezone.now()
        )
        RunEvent.objects.create(
            run_id=run_id,
            from_state=current,
            to_state=to_state,
            reason=reason,
            cause=cause,
            by=by,
        )
        _run_event(
            run_id=run_id,
            reservation_id=reservation_id,
            owner_id=owner_id,
            resource=resource,
            from_state=current,
            to_state=to_state,
            reason=reason,
            cause=cause,
        )
    logger.info("run %s: %s → %s (%s) %s", run_id, current, to_state, cause, reason)
    return True


def run_give_up(*, run: Run, by: User, reason: str) -> None:
    """An admin marks a run failed that will never finish by itself; audited."""
    if not by.is_testbed_admin:
        raise NotAllowed("Only admins give up on runs.")
    if not reason.strip():
        raise InvalidInput.on_field("reason", "Say why the run is given up.")
    with transaction.atomic():
        changed = run_transition(
            run_id=run.pk,
            to_state=RunState.FAILED,
            cause=Cause.ADMIN,
            reason=f"given up by {by.get_username()}: {reason}",
            by=by,
        )
        if not changed:
            run.refresh_from_db(fields=["state"])
            raise Conflict(
                f"The run is {run.get_state_display()}: only a scheduled run or one stuck "
                "collecting can be given up (cancel the booking to stop a running one)."
            )
        audit_record(actor=by, action="run.give_up", target=run, reason=reason)
