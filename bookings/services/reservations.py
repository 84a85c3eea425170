"""Reservations: the live check of a booking, and booking, moving, attaching a program to,
cancelling, deciding and completing one.

Every check that guards capacity runs inside one transaction under row locks taken in a
fixed order (the user, then the resources by id: ``_lock``), so concurrent bookings are decided
one at a time; on PostgreSQL an exclusion constraint backs the overlap check. What may be
booked, moved or cancelled is decided in ``bookings.rules``; these functions raise its first
problem.

One thing: the writes of a reservation under the booking locks (check, create, move, attach,
cancel, decide, complete); each takes the same locks in the same order and raises the rules'
first problem, which is easiest to see when they sit together.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from functools import partial
from typing import Literal

from django.db import IntegrityError, transaction
from django.utils import timezone

from bookings import queries
from bookings.choices import BookedVia, Channel, ReservationState
from bookings.events import reservation_event_record
from bookings.leases import (
    booking_guard,
    lease_move,
    lease_record,
    lease_release,
    lease_take,
    leases_clear_own_orphans,
    leases_for_check,
    leases_refresh,
    scheduler_owned,
)
from bookings.models import Reservation, ReservationItem, Resource
from bookings.rules import (
    Problem,
    Program,
    attach_problems,
    aware_utc,
    booking_problems,
    cancel_problems,
    decision_problems,
    move_problems,
    needs_approval,
    request_problems,
)
from bookings.scheduler import Lease
from bookings.tasks import lease_cancel
from core.accounts.models import User
from core.audit.services import audit_record
from core.errors import Conflict, DomainError

logger = logging.getLogger(__name__)


def _release_lease_after_commit(reservation: Reservation) -> None:
    """A booking that ended early gives its lease back once that is committed (retried; the
    scheduler sweep cancels it too, as an orphan, if every try fails)."""
    if reservation.lease_uuid:
        transaction.on_commit(partial(lease_cancel.delay, reservation.lease_uuid))


def _door(via: Channel | None) -> str:
    """The door a change came through, as its audit row records it ("" when not said)."""
    return via.value if via is not None else ""


def _event(
    type: str,
    reservation: Reservation,
    *,
    by: User | None,
    via: Channel | None,
    resources: Sequence[str] | None = None,
) -> None:
    """The change's event, in its transaction (``bookings.events``)."""
    reservation_event_record(
        type,
        reservation,
        by=by.get_username() if by is not None else None,
        via=_door(via),
        resources=resources,
    )


def _hold_items(reservation: Reservation, items: list[ReservationItem]) -> None:
    """Keep the items just written as the reservation's ``items``, as a prefetch leaves
    them: whoever answers with the new booking reads them (and their resources) without
    asking the database again."""
    held = reservation.items.all()
    held._result_cache = items
    held._prefetch_done = True  # type: ignore[attr-defined]
    reservation._prefetched_objects_cache = {"items": held}  # type: ignore[attr-defined]


def _refuse(problems: Sequence[Problem]) -> None:
    """Raise the first problem, if there is one."""
    if problems:
        raise problems[0].as_error()


def _lock(owner: User, resources: Sequence[Resource]) -> list[Resource]:
    """Serialise bookings per user (quotas) and per resource (overlaps), in a fixed order.

    Returns the resources as locked: whether one is in service is judged on these rows, so
    taking it out of service while someone books it cannot let the booking through. The
    locking query (and why SQLite needs none) is ``queries.resources_locked``.
    """
    return queries.resources_locked(owner.pk, [r.pk for r in resources])


def _check(
    *,
    owner: User,
    resources: Sequence[Resource],
    start_at: datetime,
    end_at: datetime,
    program: Program | None,
    now: datetime,
    exclude_id: int | None,
    override_reason: str,
    program_required: bool = True,
    scheduler_leases: Sequence[Lease] | None = None,
    own_lease_uuid: str = "",
) -> list[str]:
    """Raise the first problem with this booking; returns the quota rules overridden."""
    problems = booking_problems(
        owner=owner,
        resources=resources,
        start_at=start_at,
        end_at=end_at,
        program=program,
        now=now,
        exclude_reservation_id=exclude_id,
        first_only=True,
        program_required=program_required,
        scheduler_owned=scheduler_owned(resources),
        scheduler_leases=scheduler_leases,
        own_lease_uuid=own_lease_uuid,
    )
    if not problems:
        return []
    problem = problems[0]
    if problem.overridable and override_reason:
        return list(problem.messages)
    raise problem.as_error()


@dataclass(frozen=True)
class ReservationCheck:
    """The live check's answer: every problem, and where the scheduler's leases came from."""

    problems: list[Problem]
    needs_approval: bool
    # "scheduler": asked a moment ago, as booking asks it; "mirror": it could not be reached,
    # and ``notice`` says so; None: not asked (nothing checked is the scheduler's, or the
    # period is empty).
    leases_from: Literal["scheduler", "mirror"] | None = None
    notice: str = ""

    @property
    def fits(self) -> bool:
        return not self.problems


def reservation_check(
    *,
    owner: User,
    resources: Sequence[Resource],
    start_at: datetime,
    end_at: datetime,
    program: Program | None,
    by: User | None = None,
    override_reason: str = "",
    now: datetime | None = None,
    exclude_reservation_id: int | None = None,
    program_owner_id: int | None = None,
) -> ReservationCheck:
    """Everything that would refuse this booking now, all at once (``reservation_create``
    raises the first of the same problems under its locks); nothing is written or locked.

    ``exclude_reservation_id``: the booking being moved (itself and its lease excluded).
    Quota problems are listed even with an ``override_reason`` (the admin sees what is
    overridden).
    """
    now = now or timezone.now()
    by = by or owner
    problems = request_problems(
        owner=owner,
        by=by,
        resources=resources,
        override_reason=override_reason,
        program_owner_id=program_owner_id,
    )
    if any(p.code == "resources" for p in problems):
        return ReservationCheck(problems, needs_approval=False)  # nothing else can be judged
    start_at = aware_utc(start_at, "start_at")
    end_at = aware_utc(end_at, "end_at")
    owned = scheduler_owned(resources)
    fresh: list[Lease] | None = None
    leases_from: Literal["scheduler", "mirror"] | None = None
    notice = ""
    if owned and start_at < end_at:
        fresh, notice = leases_for_check(start_at=start_at, end_at=end_at)
        leases_from = "scheduler" if fresh is not None else "mirror"
    problems += booking_problems(
        owner=owner,
        resources=resources,
        start_at=start_at,
        end_at=end_at,
        program=program,
        now=now,
        exclude_reservation_id=exclude_reservation_id,
        scheduler_owned=owned,
        scheduler_leases=fresh,
        own_lease_uuid=_lease_uuid_of(exclude_reservation_id),
    )
    return ReservationCheck(
        problems,
        needs_approval=needs_approval(resources=resources, by=by),
        leases_from=leases_from,
        notice=notice,
    )


def _lease_uuid_of(reservation_id: int | None) -> str:
    """The lease the booking being moved holds ("" when none is moved, or it holds none)."""
    if reservation_id is None:
        return ""
    return (
        Reservation.objects.filter(pk=reservation_id).values_list("lease_uuid", flat=True).first()
        or ""
    )


def reservation_create(
    *,
    owner: User,
    resources: Sequence[Resource] | None = None,
    resource: Resource | None = None,
    start_at: datetime,
    end_at: datetime,
    program: Program | None = None,
    title: str = "",
    by: User | None = None,
    override_reason: str = "",
    ip: str | None = None,
    now: datetime | None = None,
    program_required: bool = True,
    booked_via: BookedVia = BookedVia.PORTAL,
    program_owner_id: int | None = None,
    via: Channel | None = None,
) -> Reservation:
    """Book ``resources`` for ``[start_at, end_at)``.

    ``program`` is what a mobile node among them will run; it is checked against the node
    (velocity, length) but not stored here — the runs layer books a run and its reservation
    together by calling this inside its own transaction, and says who wrote the program
    (``program_owner_id``). ``by`` is who acts (an admin booking for ``owner``; defaults to
    ``owner``). Only an admin may pass ``override_reason``, which lets the booking past quota
    rules (never past another booking or a maintenance window) and is recorded in the audit
    log. Every refusal is a problem of ``bookings.rules``.

    Resources the testbed's scheduler owns are held by one lease there, taken under the
    booking's locks before the reservation is written and named after its public id; any
    failure after that cancels the lease again (``bookings/leases.py``). A scheduler that
    does not answer is a 503 and nothing is booked.
    """
    now = now or timezone.now()
    booking = _create_check_request(
        owner=owner,
        by=by or owner,
        resources=list(resources or ([resource] if resource is not None else [])),
        start_at=start_at,
        end_at=end_at,
        override_reason=override_reason,
        program_owner_id=program_owner_id,
    )
    public_id = uuid.uuid4()
    lease: Lease | None = None

    try:
        with transaction.atomic():
            overridden = _create_check_locked(
                booking, program=program, now=now, program_required=program_required
            )
            if booking.owned:
                booking_guard(public_id)
                lease = lease_take(
                    public_id=public_id,
                    start_at=booking.start_at,
                    end_at=booking.end_at,
                    resources=booking.owned,
                )
            reservation = _create_write(
                booking,
                public_id=public_id,
                lease=lease,
                overridden=overridden,
                title=title,
                booked_via=booked_via,
                ip=ip,
                via=via,
            )
    except IntegrityError as exc:
        if lease is not None:
            lease_release(lease_uuid=lease.uuid)
        # The exclusion constraint caught an overlap the locked check could not see
        # (only possible if something wrote around the services).
        raise Conflict.on_field("start_at", "That slot was just taken.") from exc
    except BaseException:
        if lease is not None:
            lease_release(lease_uuid=lease.uuid)
        raise
    logger.info(
        "reservation %s (%s) created by %s",
        reservation.pk,
        booking.state,
        booking.by.get_username(),
    )
    return reservation


@dataclass(frozen=True)
class _NewBooking:
    """A booking ``reservation_create`` is making, as its checks before the locks left it."""

    owner: User
    by: User
    resources: list[Resource]
    start_at: datetime  # aware, in UTC
    end_at: datetime
    override_reason: str  # stripped
    waits: bool  # for an admin's approval
    owned: list[Resource]  # those the testbed's scheduler owns
    # The scheduler's leases over the period, asked a moment ago (None: not asked).
    fresh: list[Lease] | None

    @property
    def state(self) -> ReservationState:
        return ReservationState.REQUESTED if self.waits else ReservationState.CONFIRMED


def _create_check_request(
    *,
    owner: User,
    by: User,
    resources: list[Resource],
    start_at: datetime,
    end_at: datetime,
    override_reason: str,
    program_owner_id: int | None,
) -> _NewBooking:
    """The checks before the locks: raise the first problem with the request itself (who
    books what for whom), put the period in UTC, and ask the scheduler for its leases over
    the period when it owns any of the resources. Nothing is locked or written here."""
    _refuse(
        request_problems(
            owner=owner,
            by=by,
            resources=resources,
            override_reason=override_reason,
            program_owner_id=program_owner_id,
        )
    )
    override_reason = override_reason.strip()
    start_at = aware_utc(start_at, "start_at")
    end_at = aware_utc(end_at, "end_at")
    waits = needs_approval(resources=resources, by=by)
    owned = scheduler_owned(resources)
    fresh: list[Lease] | None = None
    if owned and start_at < end_at:
        # The leases made elsewhere a moment ago refuse this booking by name, not by a 409
        # from the scheduler (which names no lease).
        fresh = leases_refresh(start_at=start_at, end_at=end_at)
    return _NewBooking(
        owner=owner,
        by=by,
        resources=resources,
        start_at=start_at,
        end_at=end_at,
        override_reason=override_reason,
        waits=waits,
        owned=owned,
        fresh=fresh,
    )


def _create_check_locked(
    booking: _NewBooking, *, program: Program | None, now: datetime, program_required: bool
) -> list[str]:
    """The check under the booking's locks (the user, then the resources: ``_lock``), which
    ``reservation_create`` holds until it commits: raise the first problem with the booking;
    returns the quota rules its ``override_reason`` overrides."""
    locked = _lock(booking.owner, booking.resources)
    fresh = booking.fresh
    if fresh is not None:
        # A retry of a booking killed after its lease finds that lease here.
        fresh = leases_clear_own_orphans(
            fresh,
            resources=booking.owned,
            start_at=booking.start_at,
            end_at=booking.end_at,
            now=now,
        )
    return _check(
        owner=booking.owner,
        resources=locked,
        start_at=booking.start_at,
        end_at=booking.end_at,
        program=program,
        now=now,
        exclude_id=None,
        override_reason=booking.override_reason,
        program_required=program_required,
        scheduler_leases=fresh,
    )


def _create_write(
    booking: _NewBooking,
    *,
    public_id: uuid.UUID,
    lease: Lease | None,
    overridden: list[str],
    title: str,
    booked_via: BookedVia,
    ip: str | None,
    via: Channel | None,
) -> Reservation:
    """Write the checked booking under its locks: the reservation (holding ``lease``, if the
    scheduler's resources are among its own), its items, the lease's mirror, the audit rows,
    and the owner's notice once committed."""
    start_at, end_at = booking.start_at, booking.end_at
    reservation = Reservation(
        owner=booking.owner,
        start_at=start_at,
        end_at=end_at,
        state=booking.state,
        title=title,
        override_reason=booking.override_reason if overridden else "",
        public_id=public_id,
        lease_uuid=lease.uuid if lease is not None else "",
        booked_via=booked_via,
    )
    # The window was checked under these locks and the database enforces the constraint again;
    # re-running it here would only cost round trips under the lock (a fresh uuid4
    # public id needs no uniqueness query either: the unique index stands behind it).
    reservation.full_clean(exclude=["owner", "public_id"], validate_constraints=False)
    reservation.save()
    items = ReservationItem.objects.bulk_create(
        ReservationItem(reservation=reservation, resource=r, start_at=start_at, end_at=end_at)
        for r in booking.resources
    )
    _hold_items(reservation, items)
    if lease is not None:
        lease_record(lease=lease, reservation=reservation, resources=booking.owned)
    _create_audit(booking, reservation, lease=lease, overridden=overridden, ip=ip, via=via)
    _event(
        "reservation.created",
        reservation,
        by=booking.by,
        via=via,
        resources=sorted(r.name for r in booking.resources),
    )
    return reservation


def _create_audit(
    booking: _NewBooking,
    reservation: Reservation,
    *,
    lease: Lease | None,
    overridden: list[str],
    ip: str | None,
    via: Channel | None,
) -> None:
    """The new booking's audit rows: what was booked through which door, and the quota rules
    an admin's ``override_reason`` let it past."""
    audit_record(
        actor=booking.by,
        action="reservation.create",
        target=reservation,
        ip=ip,
        owner=booking.owner.get_username(),
        resources=[r.name for r in booking.resources],
        start_at=booking.start_at.isoformat(),
        end_at=booking.end_at.isoformat(),
        state=booking.state,
        lease=lease.uuid if lease is not None else None,
        via=_door(via),
    )
    if overridden:
        audit_record(
            actor=booking.by,
            action="reservation.override",
            target=reservation,
            ip=ip,
            reason=booking.override_reason,
            overridden=overridden,
        )


def reservation_reschedule(
    *,
    reservation: Reservation,
    by: User,
    start_at: datetime,
    end_at: datetime,
    program: Program | None = None,
    ip: str | None = None,
    now: datetime | None = None,
    run_started: bool = False,
    via: Channel | None = None,
) -> Reservation:
    """Move an upcoming reservation (every check again, itself excluded).

    ``program`` is what its mobile node will run, if it holds one (see reservation_create);
    ``run_started``: that run has left the schedule, and the booking may no longer move (the
    runs layer knows, under its lock on the run).
    """
    now = now or timezone.now()
    _refuse(move_problems(reservation=reservation, by=by, now=now, run_started=run_started))
    start_at = aware_utc(start_at, "start_at")
    end_at = aware_utc(end_at, "end_at")
    fresh: list[Lease] | None = None
    if reservation.lease_uuid and start_at < end_at:
        fresh = leases_refresh(start_at=start_at, end_at=end_at)
    moved_lease: tuple[datetime, datetime] | None = None
    try:
        with transaction.atomic():
            locked = Reservation.objects.select_for_update().get(pk=reservation.pk)
            _reschedule_check_locked(
                locked,
                by=by,
                start_at=start_at,
                end_at=end_at,
                program=program,
                now=now,
                run_started=run_started,
                fresh=fresh,
            )
            before = (locked.start_at, locked.end_at)
            if locked.lease_uuid:
                lease_move(lease_uuid=locked.lease_uuid, start_at=start_at, end_at=end_at)
                moved_lease = before
            _reschedule_write(
                locked, by=by, start_at=start_at, end_at=end_at, before=before, ip=ip, via=via
            )
    except BaseException:
        if moved_lease is not None:
            # Put the lease back where the booking still is; if that fails too, the sweep
            # flags the booking when its lease no longer covers it.
            _lease_move_back(reservation.lease_uuid, *moved_lease)
        raise
    return locked


def _reschedule_check_locked(
    locked: Reservation,
    *,
    by: User,
    start_at: datetime,
    end_at: datetime,
    program: Program | None,
    now: datetime,
    run_started: bool,
    fresh: list[Lease] | None,
) -> None:
    """The checks under the booking's row lock, then its owner's and resources' (``_lock``):
    raise the first problem with moving it, or with it at its new period (itself and its
    lease excluded; its quota override kept; a program required only of a portal booking)."""
    _refuse(move_problems(reservation=locked, by=by, now=now, run_started=run_started))
    resources = _lock(locked.owner, list(locked.resources.all()))
    _check(
        owner=locked.owner,
        resources=resources,
        start_at=start_at,
        end_at=end_at,
        program=program,
        now=now,
        exclude_id=locked.pk,
        override_reason=locked.override_reason,
        program_required=locked.booked_via == BookedVia.PORTAL,
        scheduler_leases=fresh,
        own_lease_uuid=locked.lease_uuid,
    )


def _reschedule_write(
    locked: Reservation,
    *,
    by: User,
    start_at: datetime,
    end_at: datetime,
    before: tuple[datetime, datetime],
    ip: str | None,
    via: Channel | None,
) -> None:
    """Write the checked move under the booking's locks: its period and its items', and the
    audit row (the period ``before`` and after, the door)."""
    locked.start_at, locked.end_at = start_at, end_at
    locked.full_clean()
    locked.save(update_fields=["start_at", "end_at", "updated_at"])
    locked.items.update(start_at=start_at, end_at=end_at)
    audit_record(
        actor=by,
        action="reservation.reschedule",
        target=locked,
        ip=ip,
        before=(before[0].isoformat(), before[1].isoformat()),
        after=(start_at.isoformat(), end_at.isoformat()),
        via=_door(via),
    )
    _event("reservation.moved", locked, by=by, via=via)


def _lease_move_back(lease_uuid: str, start_at: datetime, end_at: datetime) -> None:
    """Move a booking's lease back to where the booking still is, after its move failed; a
    failure here is logged, not raised (the caller raises what made the move fail)."""
    try:
        lease_move(lease_uuid=lease_uuid, start_at=start_at, end_at=end_at)
    except DomainError as exc:
        logger.error("lease %s not moved back: %s", lease_uuid, exc.message)


def reservation_program_attach(
    *,
    reservation: Reservation,
    by: User,
    program: Program,
    program_owner_id: int,
    has_program: bool,
    ip: str | None = None,
    now: datetime | None = None,
    via: Channel | None = None,
) -> Reservation:
    """Let a booking made through the lease API (it holds its robot without a program) run
    ``program``: refused as a new booking with it would be, under the same locks.

    The runs layer calls this inside its transaction and makes the run; it says whether the
    booking has a program already (``has_program``) and who wrote this one.
    """
    now = now or timezone.now()
    with transaction.atomic():
        locked = Reservation.objects.select_for_update().get(pk=reservation.pk)
        _refuse(
            attach_problems(
                reservation=locked,
                by=by,
                now=now,
                has_program=has_program,
                program_owner_id=program_owner_id,
            )
        )
        resources = _lock(locked.owner, list(locked.resources.all()))
        _check(
            owner=locked.owner,
            resources=resources,
            start_at=locked.start_at,
            end_at=locked.end_at,
            program=program,
            now=now,
            exclude_id=locked.pk,
            override_reason=locked.override_reason,
            own_lease_uuid=locked.lease_uuid,
        )
        audit_record(actor=by, action="reservation.attach", target=locked, ip=ip, via=_door(via))
    return locked


def reservation_cancel(
    *,
    reservation: Reservation,
    by: User,
    reason: str = "",
    ip: str | None = None,
    via: Channel | None = None,
) -> Reservation:
    """Cancel a reservation: its resources are free again at once.

    A run booked with it is withdrawn by the runs layer, which calls this in its transaction.
    Cancelled by anyone but its owner, the owner is told by whom and ``via`` what.
    """
    with transaction.atomic():
        locked = Reservation.objects.select_for_update().get(pk=reservation.pk)
        _refuse(cancel_problems(reservation=locked, by=by, reason=reason))
        locked.state = ReservationState.CANCELLED
        locked.cancelled_by = by
        locked.cancel_reason = reason
        locked.save(update_fields=["state", "cancelled_by", "cancel_reason", "updated_at"])
        locked.items.update(active=False)
        _release_lease_after_commit(locked)
        audit_record(
            actor=by,
            action="reservation.cancel",
            target=locked,
            ip=ip,
            reason=reason,
            via=_door(via),
        )
        _event("reservation.cancelled", locked, by=by, via=via)
    logger.info("reservation %s cancelled by %s", reservation.pk, by.get_username())
    return locked


def reservation_decide(
    *,
    reservation: Reservation,
    by: User,
    approve: bool,
    reason: str = "",
    ip: str | None = None,
    via: Channel | None = None,
) -> Reservation:
    """An admin approves or rejects a requested reservation; the owner is told.

    A rejected reservation frees its resources; its run is withdrawn by the runs layer.
    """
    _refuse(decision_problems(reservation=reservation, by=by, approve=approve, reason=reason))
    with transaction.atomic():
        locked = Reservation.objects.select_for_update().get(pk=reservation.pk)
        _refuse(decision_problems(reservation=locked, by=by, approve=approve, reason=reason))
        locked.state = ReservationState.CONFIRMED if approve else ReservationState.REJECTED
        locked.decided_by = by
        locked.decided_at = timezone.now()
        locked.decision_reason = reason
        locked.save(
            update_fields=["state", "decided_by", "decided_at", "decision_reason", "updated_at"]
        )
        if not approve:
            locked.items.update(active=False)
            _release_lease_after_commit(locked)
        audit_record(
            actor=by,
            action="reservation.approve" if approve else "reservation.reject",
            target=locked,
            ip=ip,
            reason=reason,
            via=_door(via),
        )
        _event(
            "reservation.approved" if approve else "reservation.rejected", locked, by=by, via=via
        )
    return locked


def reservation_complete(*, reservation_id: int) -> bool:
    """Mark a confirmed reservation used up (its run completed); False if it was not confirmed."""
    return bool(
        Reservation.objects.filter(pk=reservation_id, state=ReservationState.CONFIRMED).update(
            state=ReservationState.COMPLETED, updated_at=timezone.now()
        )
    )
