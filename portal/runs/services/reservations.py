"""Reservations with a robot program: a reservation and its run change together, or not at all.

Each function here opens one transaction and, inside it, calls its namesake in
``bookings/services/reservations.py`` (imported as ``without_run``: it takes the booking locks
and asks ``bookings.rules`` whether the reservation can be made) and then does the run's part.
The bookings layer knows nothing of runs: what only this layer knows (who wrote the
experiment, whether the run has left the schedule) is passed in. The two layers use one word,
*reservation*, as the model, the tables and the REST API (``/api/v1/reservations/``) do;
"booking" is the act, in the rules' names and on the pages.

This is the one door for a booking that holds or may hold a run: the pages, the REST API (and
the ``amazing`` command through it), the Django admin's actions and the testbed scheduler's
lease API all change bookings through these functions, never through ``bookings.services``
directly. ``via`` names the door; the audit row of each change records it.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from datetime import datetime, timedelta
from functools import partial

from django.conf import settings
from django.db import transaction
from django.utils import timezone

from bookings.choices import BookedVia, Channel
from bookings.leases import lease_release
from bookings.models import Reservation, Resource
from bookings.selectors import resource_first_free
from bookings.services import ReservationCheck
from bookings.services import reservations as without_run
from core.accounts.models import User
from core.errors import Conflict
from portal.experiments.models import Experiment

# The module, not its task: the tasks import the self-check's service, which books through here.
from portal.runs import tasks as run_tasks
from portal.runs.models import Run
from portal.runs.services.transitions import run_create, run_transition
from portal.runs.states import Cause, RunState

logger = logging.getLogger(__name__)


def reservation_create(
    *,
    owner: User,
    resources: Sequence[Resource] | None = None,
    resource: Resource | None = None,
    start_at: datetime,
    end_at: datetime,
    experiment: Experiment | None = None,
    title: str = "",
    by: User | None = None,
    override_reason: str = "",
    ip: str | None = None,
    now: datetime | None = None,
    booked_via: BookedVia = BookedVia.PORTAL,
    via: Channel | None = None,
) -> Reservation:
    """Book resources; on a mobile node, also schedule the run of ``experiment`` there.

    A booking made through the lease API (``booked_via``) may hold its robot without an
    experiment; one is attached later (``reservation_attach``)."""
    chosen = list(resources or ([resource] if resource is not None else []))
    mobile = next((r for r in chosen if r.is_mobile), None)
    book = partial(
        without_run.reservation_create,
        owner=owner,
        resources=chosen,
        start_at=start_at,
        end_at=end_at,
        program=experiment,
        title=title or (experiment.title if experiment is not None else ""),
        by=by,
        override_reason=override_reason,
        ip=ip,
        now=now,
        program_owner_id=experiment.owner_id if experiment is not None else None,
        program_required=booked_via == BookedVia.PORTAL,
        booked_via=booked_via,
        via=via,
    )
    if mobile is None or experiment is None:
        return book()  # no run to make with it (or booking refuses it and says why)
    reservation: Reservation | None = None
    try:
        with transaction.atomic():
            reservation = book()
            run_create(
                reservation=reservation, resource=mobile, experiment=experiment, by=by or owner
            )
    except BaseException:
        # The reservation was rolled back with its run: give its lease back at once (the
        # scheduler sweep would cancel it as an orphan otherwise).
        if reservation is not None and reservation.lease_uuid:
            lease_release(lease_uuid=reservation.lease_uuid)
        raise
    return reservation


# How far ahead "Run again" looks for a free slot, and how often it looks again when the slot
# it found is taken before it could book it.
REPEAT_HORIZON = timedelta(days=62)
REPEAT_ATTEMPTS = 3


def reservation_repeat(
    *,
    run: Run,
    by: User,
    ip: str | None = None,
    now: datetime | None = None,
    via: Channel | None = None,
) -> Reservation:
    """Book ``run``'s program again, with its limits, on its robot, in the first free slot of
    its reservation's length from ``RUN_REPEAT_LEAD_S`` on ("Run again"). The new run links to
    ``run`` (``repeat_of``). Booked for ``run``'s owner by ``by``, under every booking rule."""
    now = now or timezone.now()
    length = run.end_at - run.start_at
    earliest = now + timedelta(seconds=settings.RUN_REPEAT_LEAD_S)
    owner = run.reservation.owner
    tried: tuple[datetime, datetime] | None = None
    refused: Conflict | None = None
    for _ in range(REPEAT_ATTEMPTS):
        slot = resource_first_free(
            resource=run.resource, earliest=earliest, length=length, horizon=REPEAT_HORIZON
        )
        if slot is None and not run.resource.in_service:
            # No slot because the robot is out of booking: the booking rules say why.
            slot = (earliest, earliest + length)
        if slot is None:
            raise Conflict(
                f"{run.resource.name} has no free slot of {length.total_seconds():g} s in the "
                f"next {REPEAT_HORIZON.days} days"
            )
        if refused is not None and slot == tried:
            raise refused  # the same slot again: refused for a reason other than a race
        tried = slot
        try:
            return _book_repeat(run, owner=owner, by=by, slot=slot, ip=ip, now=now, via=via)
        except Conflict as exc:
            # Someone may have taken the slot between the look and the booking: look again.
            logger.info("run %s: slot at %s refused (%s); looking again", run.pk, slot[0], exc)
            refused = exc
    assert refused is not None
    raise refused


def _book_repeat(
    run: Run,
    *,
    owner: User,
    by: User,
    slot: tuple[datetime, datetime],
    ip: str | None,
    now: datetime,
    via: Channel | None,
) -> Reservation:
    reservation: Reservation | None = None
    try:
        with transaction.atomic():
            reservation = without_run.reservation_create(
                owner=owner,
                resources=[run.resource],
                start_at=slot[0],
                end_at=slot[1],
                program=run,
                title=run.title,
                by=by,
                ip=ip,
                now=now,
                program_owner_id=run.experiment.owner_id,
                via=via,
            )
            run_create(
                reservation=reservation,
                resource=run.resource,
                experiment=run.experiment,
                by=by,
                repeat_of=run,
            )
    except BaseException:
        if reservation is not None and reservation.lease_uuid:
            lease_release(lease_uuid=reservation.lease_uuid)
        raise
    return reservation


def reservation_attach(
    *,
    reservation: Reservation,
    experiment: Experiment,
    by: User,
    ip: str | None = None,
    now: datetime | None = None,
    via: Channel | None = None,
) -> Run:
    """Attach ``experiment`` to a booking made through the lease API, before it starts: its
    robot runs it then. Every booking rule applies, as to a booking made with it."""
    with transaction.atomic():
        # Reservation first, then run: the order every path that takes both locks uses.
        locked = Reservation.objects.select_for_update().get(pk=reservation.pk)
        attached = without_run.reservation_program_attach(
            reservation=locked,
            by=by,
            program=experiment,
            program_owner_id=experiment.owner_id,
            has_program=Run.objects.filter(reservation=locked).exists(),
            ip=ip,
            now=now,
            via=via,
        )
        mobile = next(r for r in attached.resources.all() if r.is_mobile)
        return run_create(reservation=attached, resource=mobile, experiment=experiment, by=by)


def reservation_reschedule(
    *,
    reservation: Reservation,
    by: User,
    start_at: datetime,
    end_at: datetime,
    ip: str | None = None,
    now: datetime | None = None,
    via: Channel | None = None,
) -> Reservation:
    """Move an upcoming booking and its run; refused once the run is on its base station, or
    when the run's program does not fit the new window (the run is the booking's program)."""
    with transaction.atomic():
        # Reservation first, then run: the order every path that takes both locks uses.
        locked = Reservation.objects.select_for_update().get(pk=reservation.pk)
        run = Run.objects.select_for_update().filter(reservation=locked).first()
        moved = without_run.reservation_reschedule(
            reservation=locked,
            by=by,
            start_at=start_at,
            end_at=end_at,
            program=run,
            ip=ip,
            now=now,
            run_started=run is not None and run.state != RunState.SCHEDULED,
            via=via,
        )
        if run is not None:
            Run.objects.filter(pk=run.pk).update(start_at=moved.start_at, end_at=moved.end_at)
    return moved


def _withdraw_run(reservation: Reservation, *, reason: str, by: User) -> None:
    """The run of a reservation that no longer holds its robot: cancelled, or withdrawn from
    its agent after commit (a running one is aborted there and collected as interrupted)."""
    run = Run.objects.filter(reservation=reservation).first()
    if run is None:
        return
    if run_transition(
        run_id=run.pk,
        to_state=RunState.CANCELLED,
        cause=Cause.BOOKING,
        from_states=[RunState.SCHEDULED],
        reason=reason,
        by=by,
    ):
        return
    if run.state in (RunState.STAGED, RunState.RUNNING):
        transaction.on_commit(partial(run_tasks.run_unstage.delay, run.pk))


def reservation_cancel(
    *,
    reservation: Reservation,
    by: User,
    reason: str = "",
    ip: str | None = None,
    via: Channel | None = None,
) -> Reservation:
    """Cancel a booking and withdraw its run (``via``: where it was cancelled, for its owner)."""
    with transaction.atomic():
        cancelled = without_run.reservation_cancel(
            reservation=reservation, by=by, reason=reason, ip=ip, via=via
        )
        _withdraw_run(cancelled, reason=reason or f"cancelled by {by.get_username()}", by=by)
    return cancelled


def reservation_decide(
    *,
    reservation: Reservation,
    by: User,
    approve: bool,
    reason: str = "",
    ip: str | None = None,
    via: Channel | None = None,
) -> Reservation:
    """An admin approves or rejects a requested booking; a rejected one's run is withdrawn."""
    with transaction.atomic():
        decided = without_run.reservation_decide(
            reservation=reservation, by=by, approve=approve, reason=reason, ip=ip, via=via
        )
        if not approve:
            _withdraw_run(decided, reason=f"request rejected: {reason}", by=by)
    return decided


def reservation_check(
    *,
    owner: User,
    resources: Sequence[Resource],
    start_at: datetime,
    end_at: datetime,
    experiment: Experiment | None,
    by: User | None = None,
    override_reason: str = "",
    exclude_reservation_id: int | None = None,
    now: datetime | None = None,
) -> ReservationCheck:
    """Everything that would refuse this booking now, for the calendar's live check.

    The same rules ``without_run.reservation_create`` applies under its locks
    (``bookings.rules``), all of them at once and without locking, the testbed scheduler asked
    as booking asks it; nothing is written. ``by``: who would book (an admin, for ``owner``;
    default ``owner``).
    """
    return without_run.reservation_check(
        owner=owner,
        resources=resources,
        start_at=start_at,
        end_at=end_at,
        program=experiment,
        by=by,
        override_reason=override_reason,
        now=now or timezone.now(),
        exclude_reservation_id=exclude_reservation_id,
        program_owner_id=experiment.owner_id if experiment is not None else None,
    )
