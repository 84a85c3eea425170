"""Writes for reservations, blackouts and quota policies, and the live check of a booking.

Every check that guards capacity runs inside one transaction under row locks taken in a
fixed order (the user, then the resources by id), so concurrent bookings are decided one at
a time; on PostgreSQL an exclusion constraint backs the overlap check. What may be booked,
moved or cancelled is decided in ``bookings.rules``; these functions raise its first problem.
"""

from __future__ import annotations

import logging
import math
import uuid
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime
from functools import partial
from typing import Any, Literal

from django.core.exceptions import ValidationError
from django.db import IntegrityError, connection, transaction
from django.utils import timezone

from bookings.choices import (
    BookedVia,
    Channel,
    ReservationState,
    ResourceKind,
)
from bookings.leases import (
    booking_guard,
    lease_move,
    lease_record,
    lease_release,
    lease_take,
    leases_clear_own_orphans,
    leases_for_check,
    leases_refresh,
    scheduler_client,
    scheduler_enabled,
    scheduler_owned,
)
from bookings.models import (
    HOLD_REASON_MAX_CHARS,
    Blackout,
    QuotaPolicy,
    Reservation,
    ReservationItem,
    Resource,
    placeholders,
    table_sql,
)
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
from bookings.scheduler import Lease, SchedulerError
from bookings.tasks import lease_cancel, reservation_notify
from core.accounts.models import User
from core.audit.counters import event_count
from core.audit.services import audit_record
from core.errors import Conflict, DomainError, InvalidInput, NotAllowed

logger = logging.getLogger(__name__)


def _notify(kind: str, reservation_id: int, **extra: Any) -> None:
    transaction.on_commit(partial(reservation_notify.delay, kind, reservation_id, **extra))


def _release_lease_after_commit(reservation: Reservation) -> None:
    """A booking that ended early gives its lease back once that is committed (retried; the
    scheduler sweep cancels it too, as an orphan, if every try fails)."""
    if reservation.lease_uuid:
        transaction.on_commit(partial(lease_cancel.delay, reservation.lease_uuid))


def _door(via: Channel | None) -> str:
    """The door a change came through, as its audit row records it ("" when not said)."""
    return via.value if via is not None else ""


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
    taking it out of service while someone books it cannot let the booking through.
    """
    ids = sorted({r.pk for r in resources})
    if connection.vendor != "postgresql":
        # SQLite has no row locks: each transaction takes the database's write lock as it
        # begins (``transaction_mode`` IMMEDIATE in settings), so bookings run one at a time.
        return list(Resource.objects.filter(pk__in=ids).order_by("pk"))
    # One round trip: the user's row first (the CTE yields it before the join can give a
    # resource row to lock), then the resources in id order.
    in_ids = placeholders(len(ids))
    return list(
        Resource.objects.raw(
            f"WITH owner AS MATERIALIZED (SELECT id FROM {table_sql(User)} WHERE id = %s "  # noqa: S608
            f"FOR UPDATE) SELECT r.* FROM {table_sql(Resource)} r, owner WHERE r.id IN ({in_ids}) "
            "ORDER BY r.id FOR UPDATE OF r",
            [owner.pk, *ids],
        )
    )


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
class BookingCheck:
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
) -> BookingCheck:
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
        return BookingCheck(problems, needs_approval=False)  # nothing else can be judged
    start_at = aware_utc(start_at, "start_at")
    end_at = aware_utc(end_at, "end_at")
    owned = scheduler_owned(resources)
    fresh: list[Lease] | None = None
    leases_from: Literal["scheduler", "mirror"] | None = None
    notice = ""
    if owned and start_at < end_at:
        fresh, notice = leases_for_check(start_at=start_at, end_at=end_at)
        leases_from = "scheduler" if fresh is not None else "mirror"
    own_lease_uuid = ""
    if exclude_reservation_id is not None:
        own_lease_uuid = (
            Reservation.objects.filter(pk=exclude_reservation_id)
            .values_list("lease_uuid", flat=True)
            .first()
            or ""
        )
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
        own_lease_uuid=own_lease_uuid,
    )
    return BookingCheck(
        problems,
        needs_approval=needs_approval(resources=resources, by=by),
        leases_from=leases_from,
        notice=notice,
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
    by = by or owner
    resources = list(resources or ([resource] if resource is not None else []))
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
    state = ReservationState.REQUESTED if waits else ReservationState.CONFIRMED
    owned = scheduler_owned(resources)
    fresh: list[Lease] | None = None
    if owned and start_at < end_at:
        # The leases made elsewhere a moment ago refuse this booking by name, not by a 409
        # from the scheduler (which names no lease).
        fresh = leases_refresh(start_at=start_at, end_at=end_at)
    public_id = uuid.uuid4()
    lease: Lease | None = None

    try:
        with transaction.atomic():
            locked = _lock(owner, resources)
            if fresh is not None:
                # A retry of a booking killed after its lease finds that lease here.
                fresh = leases_clear_own_orphans(
                    fresh, resources=owned, start_at=start_at, end_at=end_at, now=now
                )
            overridden = _check(
                owner=owner,
                resources=locked,
                start_at=start_at,
                end_at=end_at,
                program=program,
                now=now,
                exclude_id=None,
                override_reason=override_reason,
                program_required=program_required,
                scheduler_leases=fresh,
            )
            if owned:
                booking_guard(public_id)
                lease = lease_take(
                    public_id=public_id, start_at=start_at, end_at=end_at, resources=owned
                )
            reservation = Reservation(
                owner=owner,
                start_at=start_at,
                end_at=end_at,
                state=state,
                title=title,
                override_reason=override_reason if overridden else "",
                public_id=public_id,
                lease_uuid=lease.uuid if lease is not None else "",
                booked_via=booked_via,
            )
            # The window was checked above and the database enforces the constraint again;
            # re-running it here would only cost round trips under the lock (a fresh uuid4
            # public id needs no uniqueness query either: the unique index stands behind it).
            reservation.full_clean(exclude=["owner", "public_id"], validate_constraints=False)
            reservation.save()
            items = ReservationItem.objects.bulk_create(
                ReservationItem(
                    reservation=reservation, resource=r, start_at=start_at, end_at=end_at
                )
                for r in resources
            )
            _hold_items(reservation, items)
            if lease is not None:
                lease_record(lease=lease, reservation=reservation, resources=owned)
            audit_record(
                actor=by,
                action="reservation.create",
                target=reservation,
                ip=ip,
                owner=owner.get_username(),
                resources=[r.name for r in resources],
                start_at=start_at.isoformat(),
                end_at=end_at.isoformat(),
                state=state,
                lease=lease.uuid if lease is not None else None,
                via=_door(via),
            )
            if overridden:
                audit_record(
                    actor=by,
                    action="reservation.override",
                    target=reservation,
                    ip=ip,
                    reason=override_reason,
                    overridden=overridden,
                )
            _notify("requested" if waits else "confirmed", reservation.pk)
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
    logger.info("reservation %s (%s) created by %s", reservation.pk, state, by.get_username())
    return reservation


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
            before = (locked.start_at, locked.end_at)
            if locked.lease_uuid:
                lease_move(lease_uuid=locked.lease_uuid, start_at=start_at, end_at=end_at)
                moved_lease = before
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
    except BaseException:
        if moved_lease is not None:
            # Put the lease back where the booking still is; if that fails too, the sweep
            # flags the booking when its lease no longer covers it.
            try:
                lease_move(
                    lease_uuid=reservation.lease_uuid,
                    start_at=moved_lease[0],
                    end_at=moved_lease[1],
                )
            except DomainError as exc:
                logger.error("lease %s not moved back: %s", reservation.lease_uuid, exc.message)
        raise
    return locked


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
        by_admin = by.pk != locked.owner_id
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
        if by_admin:
            _notify("cancelled", locked.pk, via=via.value if via is not None else "")
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
        _notify("approved" if approve else "rejected", locked.pk)
    return locked


def reservation_complete(*, reservation_id: int) -> bool:
    """Mark a confirmed reservation used up (its run completed); False if it was not confirmed."""
    return bool(
        Reservation.objects.filter(pk=reservation_id, state=ReservationState.CONFIRMED).update(
            state=ReservationState.COMPLETED, updated_at=timezone.now()
        )
    )


def resource_set_service(
    *, resource: Resource, by: User, enabled: bool, reason: str, ip: str | None = None
) -> Resource:
    """Take a resource out of service (no new bookings) or back in; audited.

    Back in service also lifts the health check's hold (``resource_hold``): only an admin
    returns a robot the health check took out, and the audit keeps the hold it lifted.
    """
    if not by.is_testbed_admin:
        raise NotAllowed("Only admins take resources in or out of service.")
    if not reason.strip():
        raise InvalidInput.on_field("reason", "Say why.")
    with transaction.atomic():
        # The same row lock bookings take: none is half-way through while this changes.
        locked = Resource.objects.select_for_update().get(pk=resource.pk)
        lifted = locked.hold_reason if enabled else ""
        locked.enabled = enabled
        if enabled:
            locked.hold_reason, locked.held_at, locked.hold_notified_at = "", None, None
        locked.save(update_fields=["enabled", "hold_reason", "held_at", "hold_notified_at"])
        audit_record(
            actor=by,
            action="resource.in_service" if enabled else "resource.out_of_service",
            target=locked,
            ip=ip,
            reason=reason,
            **({"lifted_hold": lifted} if lifted else {}),
        )
    return locked


def resource_hold(*, resource_id: int, reason: str) -> bool:
    """Take a robot out of booking for what its health check found; audited.

    True if this made the hold; False if it was already held (the first reason stays, and the
    admins are e-mailed once) or is out of service anyway.
    """
    with transaction.atomic():
        held = Resource.objects.filter(pk=resource_id, enabled=True, hold_reason="").update(
            hold_reason=reason[:HOLD_REASON_MAX_CHARS],
            held_at=timezone.now(),
            hold_notified_at=None,
        )
        if held:
            resource = Resource.objects.get(pk=resource_id)
            audit_record(actor=None, action="resource.hold", target=resource, reason=reason)
            event_count("robot_holds", resource=resource.name)
    return bool(held)


# The hold of a robot whose base-station agent the portal cannot reach for want of
# configuration (no token for it): the health check and the demo set-up make it.
AGENT_NOT_CONFIGURED = "agent not configured"


def resource_hold_lift(*, resource_id: int, reason_prefix: str, why: str) -> bool:
    """Lift a hold the system made for a cause the system knows is gone (a robot's agent
    configured again); audited. Only a hold whose reason starts with ``reason_prefix``:
    every other hold stays for an admin to lift. True if a hold was lifted."""
    with transaction.atomic():
        locked = Resource.objects.select_for_update().filter(pk=resource_id).first()
        if locked is None or not locked.hold_reason.startswith(reason_prefix):
            return False
        lifted = locked.hold_reason
        locked.hold_reason, locked.held_at, locked.hold_notified_at = "", None, None
        locked.save(update_fields=["hold_reason", "held_at", "hold_notified_at"])
        audit_record(
            actor=None, action="resource.hold_lifted", target=locked, reason=why, lifted_hold=lifted
        )
    return True


def resource_agent_unreachable(*, resource_id: int, at: datetime) -> datetime:
    """Record that the robot's agent did not answer at ``at``; returns since when it has not
    (``at``, or the first failed check of this row). Written once per row of failures."""
    Resource.objects.filter(pk=resource_id, agent_unreachable_since__isnull=True).update(
        agent_unreachable_since=at
    )
    since = (
        Resource.objects.filter(pk=resource_id)
        .values_list("agent_unreachable_since", flat=True)
        .first()
    )
    return since or at


def resource_agent_reachable(*, resource_id: int) -> None:
    """The robot's agent answered: the next failure starts a new count."""
    Resource.objects.filter(pk=resource_id, agent_unreachable_since__isnull=False).update(
        agent_unreachable_since=None
    )


@dataclass(frozen=True)
class AgentLimits:
    """A robot's limits as its base-station agent reports them in ``GET /status``."""

    max_velocity_mps: float
    max_accel_mps2: float
    robot_hard_max_velocity_mps: float | None


def resource_record_agent_limits(*, resource_id: int, limits: AgentLimits) -> bool:
    """Record what the robot's agent reports of its limits; True when they changed.

    Written only on a change (the health sweep reads every agent every few seconds).
    Booking reads them: a program is checked against the stricter of the resource's limit
    and these (``bookings.rules.velocity_limit``).
    """
    values = {
        "agent_max_velocity_mps": limits.max_velocity_mps,
        "agent_max_accel_mps2": limits.max_accel_mps2,
        "robot_hard_max_velocity_mps": limits.robot_hard_max_velocity_mps,
    }
    unchanged = Resource.objects.filter(pk=resource_id, **values).exists()
    if unchanged:
        return False
    return bool(
        Resource.objects.filter(pk=resource_id).update(**values, agent_limits_at=timezone.now())
    )


def blackout_create(
    *,
    by: User,
    start_at: datetime,
    end_at: datetime,
    reason: str,
    resources: Iterable[Resource] = (),
    all_resources: bool = False,
    ip: str | None = None,
) -> tuple[Blackout, list[Reservation]]:
    """Declare a maintenance window; returns it and the reservations it conflicts with.

    Existing reservations are not cancelled (an admin decides); they are flagged, and their
    owners and the admins are told.
    """
    if not by.is_testbed_admin:
        raise NotAllowed("Only admins declare maintenance windows.")
    resources = list(resources)
    if not resources and not all_resources:
        raise InvalidInput.on_field("resources", "Choose the resources, or all of them.")
    if not reason.strip():
        raise InvalidInput.on_field("reason", "Say what the maintenance is.")
    start_at = aware_utc(start_at, "start_at")
    end_at = aware_utc(end_at, "end_at")
    if end_at <= start_at:
        raise InvalidInput.on_field("end_at", "The end must be after the start.")
    with transaction.atomic():
        blackout = Blackout(
            start_at=start_at,
            end_at=end_at,
            reason=reason.strip(),
            all_resources=all_resources,
            created_by=by,
        )
        blackout.full_clean()
        blackout.save()
        blackout.resources.set(resources)
        items = ReservationItem.objects.overlapping(start_at, end_at).filter(active=True)
        if not all_resources:
            items = items.filter(resource__in=resources)
        conflicted = list(
            Reservation.objects.filter(pk__in=items.values("reservation_id")).order_by("start_at")
        )
        local = timezone.localtime
        note = (
            f"Overlaps maintenance “{blackout.reason}” "
            f"({local(start_at):%Y-%m-%d %H:%M} – {local(end_at):%Y-%m-%d %H:%M})."
        )
        Reservation.objects.filter(pk__in=[r.pk for r in conflicted]).update(conflict=note)
        audit_record(
            actor=by,
            action="blackout.create",
            target=blackout,
            ip=ip,
            reason=reason,
            resources="all" if all_resources else [r.name for r in resources],
            conflicts=[r.pk for r in conflicted],
        )
        for r in conflicted:
            _notify("blackout_conflict", r.pk, blackout_id=blackout.pk)
    return blackout, conflicted


QUOTA_FIELDS = (
    "name",
    "user",
    "group",
    "resource",
    "resource_group",
    "period",
    "max_hours",
    "max_count",
    "max_length_s",
    "min_notice_s",
    "max_advance_s",
    "max_future",
    "active",
)


def quota_policy_save(
    *, by: User, policy: QuotaPolicy | None = None, ip: str | None = None, **fields: Any
) -> QuotaPolicy:
    """Create or change a quota policy; the audit log keeps the old and new values."""
    if not by.is_testbed_admin:
        raise NotAllowed("Only admins set quotas.")
    unknown = set(fields) - set(QUOTA_FIELDS)
    if unknown:
        raise InvalidInput(f"Unknown quota fields: {', '.join(sorted(unknown))}.")
    creating = policy is None
    policy = policy or QuotaPolicy()
    before = {f: _plain(getattr(policy, f, None)) for f in QUOTA_FIELDS} if not creating else {}
    for name, value in fields.items():
        setattr(policy, name, value)
    if (policy.max_hours is not None or policy.max_count is not None) and not policy.period:
        raise InvalidInput.on_field("period", "A limit in hours or count needs a period.")
    with transaction.atomic():
        policy.full_clean()
        policy.save()
        audit_record(
            actor=by,
            action="quota.create" if creating else "quota.change",
            target=policy,
            ip=ip,
            before=before,
            after={f: _plain(getattr(policy, f, None)) for f in QUOTA_FIELDS},
        )
    return policy


def _plain(value: Any) -> Any:
    return str(value) if hasattr(value, "pk") else value


@dataclass(frozen=True)
class TestbedSpec:
    """The resources of a testbed installation: one mobile node and the fixed nodes."""

    agent_url: str
    mobile_name: str = "mobile-1"
    fixed_nodes: int = 24
    max_velocity_mps: float = 2.0
    max_accel_mps2: float = 1.0
    # The name of the agent's token in AGENT_TOKENS ("default" is AGENT_TOKEN).
    agent_token_name: str = "default"  # noqa: S105 - a name, not the secret
    mobile_description: str = "Rail robot around the roof of IT building 1"
    # The fixed nodes by name, as the testbed's scheduler lists them; ``node-01`` … otherwise.
    fixed_node_names: tuple[str, ...] = ()

    def fixed_names(self) -> tuple[str, ...]:
        if self.fixed_node_names:
            return self.fixed_node_names
        return tuple(f"node-{i:02d}" for i in range(1, self.fixed_nodes + 1))


def fixed_node_names_from_scheduler() -> tuple[str, ...]:
    """The nodes the testbed's scheduler leases (empty when none is configured)."""
    if not scheduler_enabled():
        return ()
    try:
        with scheduler_client() as scheduler:
            return tuple(node.name for node in scheduler.list_nodes())
    except SchedulerError as exc:
        raise InvalidInput(f"The testbed scheduler did not list its nodes: {exc.message}") from exc


def testbed_resources_ensure(spec: TestbedSpec) -> list[str]:
    """Create whichever of the spec's resources do not exist yet; returns their names.

    Existing ones are left untouched (an admin may have changed them since). Everything is
    checked before anything is written.
    """
    if not 1 <= len(spec.fixed_names()) <= 200:
        raise InvalidInput.on_field("fixed_nodes", "Give between 1 and 200 fixed nodes.")
    for field_name, value in (
        ("max_velocity_mps", spec.max_velocity_mps),
        ("max_accel_mps2", spec.max_accel_mps2),
    ):
        if not (math.isfinite(value) and value > 0):
            raise InvalidInput.on_field(field_name, f"{field_name} must be positive, got {value}.")
    wanted = [
        Resource(
            name=spec.mobile_name,
            kind=ResourceKind.MOBILE,
            description=spec.mobile_description,
            agent_url=spec.agent_url,
            agent_token_name=spec.agent_token_name,
            max_velocity_mps=spec.max_velocity_mps,
            max_accel_mps2=spec.max_accel_mps2,
        ),
        *(
            Resource(
                name=name,
                kind=ResourceKind.FIXED,
                description="Fixed node on the roof of IT building 1",
            )
            for name in spec.fixed_names()
        ),
    ]
    for resource in wanted:
        try:
            resource.full_clean(validate_unique=False)
        except ValidationError as exc:
            raise InvalidInput(f"{resource.name}: {'; '.join(exc.messages)}") from exc
    with transaction.atomic():
        existing = set(
            Resource.objects.filter(name__in=[r.name for r in wanted]).values_list(
                "name", flat=True
            )
        )
        missing = [r for r in wanted if r.name not in existing]
        Resource.objects.bulk_create(missing)
    for resource in missing:
        logger.info("resource %s created", resource.name)
    return [r.name for r in missing]
