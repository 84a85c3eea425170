"""Writes for reservations, blackouts and quota policies.

Every check that guards capacity runs inside one transaction under row locks taken in a
fixed order (the user, then the resources by id), so concurrent bookings are decided one at
a time; on PostgreSQL an exclusion constraint backs the overlap check.
"""

from __future__ import annotations

import logging
import math
import uuid
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime
from functools import partial
from typing import Any

from django.core.exceptions import ValidationError
from django.db import IntegrityError, transaction
from django.utils import timezone

from bookings.choices import (
    RESERVATION_ACTIVE_STATES,
    BookedVia,
    ReservationState,
    ResourceKind,
)
from bookings.leases import (
    booking_guard,
    lease_move,
    lease_record,
    lease_release,
    lease_take,
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
)
from bookings.rules import Program, aware_utc, booking_problems
from bookings.scheduler import Lease, SchedulerError
from bookings.tasks import lease_cancel, reservation_notify
from portal.accounts.models import User
from portal.audit.services import audit_record
from portal.errors import Conflict, DomainError, InvalidInput, NotAllowed

logger = logging.getLogger(__name__)


def _notify(kind: str, reservation_id: int, **extra: Any) -> None:
    transaction.on_commit(partial(reservation_notify.delay, kind, reservation_id, **extra))


def _release_lease_after_commit(reservation: Reservation) -> None:
    """A booking that ended early gives its lease back once that is committed (retried; the
    scheduler sweep cancels it too, as an orphan, if every try fails)."""
    if reservation.lease_uuid:
        transaction.on_commit(partial(lease_cancel.delay, reservation.lease_uuid))


def _may_book_for_others(by: User) -> bool:
    return by.is_testbed_admin or by.has_perm("bookings.lease_inbound")


def _lock(owner: User, resources: Sequence[Resource]) -> list[Resource]:
    """Serialise bookings per user (quotas) and per resource (overlaps), in a fixed order.

    Returns the resources as locked: whether one is in service is judged on these rows, so
    taking it out of service while someone books it cannot let the booking through.
    """
    list(User.objects.select_for_update().filter(pk=owner.pk).values_list("pk"))
    return list(
        Resource.objects.select_for_update().filter(pk__in=[r.pk for r in resources]).order_by("pk")
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
) -> Reservation:
    """Book ``resources`` for ``[start_at, end_at)``.

    ``program`` is what a mobile node among them will run; it is checked against the node
    (velocity, length) but not stored here — the runs layer books a run and its reservation
    together by calling this inside its own transaction. ``by`` is who acts (an admin booking
    for ``owner``; defaults to ``owner``). Only an admin may pass ``override_reason``, which
    lets the booking past quota rules (never past another booking or a maintenance window)
    and is recorded in the audit log.

    Resources the testbed's scheduler owns are held by one lease there, taken under the
    booking's locks before the reservation is written and named after its public id; any
    failure after that cancels the lease again (``bookings/leases.py``). A scheduler that
    does not answer is a 503 and nothing is booked.
    """
    now = now or timezone.now()
    by = by or owner
    resources = list(resources or ([resource] if resource is not None else []))
    if not resources:
        raise InvalidInput.on_field("resources", "Choose at least one resource.")
    if len({r.pk for r in resources}) != len(resources):
        raise InvalidInput.on_field("resources", "A resource is listed twice.")
    if by.pk != owner.pk and not _may_book_for_others(by):
        raise NotAllowed("Only admins book for someone else.")
    override_reason = override_reason.strip()
    if override_reason and not by.is_testbed_admin:
        raise NotAllowed.on_field("override_reason", "Only admins can override quotas.")
    start_at = aware_utc(start_at, "start_at")
    end_at = aware_utc(end_at, "end_at")
    needs_approval = any(r.requires_approval for r in resources) and not by.is_testbed_admin
    state = ReservationState.REQUESTED if needs_approval else ReservationState.CONFIRMED
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
            ReservationItem.objects.bulk_create(
                ReservationItem(
                    reservation=reservation, resource=r, start_at=start_at, end_at=end_at
                )
                for r in resources
            )
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
            _notify("requested" if needs_approval else "confirmed", reservation.pk)
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
) -> Reservation:
    """Move an upcoming reservation (every check again, itself excluded).

    ``program`` is what its mobile node will run, if it holds one (see reservation_create).
    """
    now = now or timezone.now()
    if reservation.owner_id != by.pk and not _may_book_for_others(by):
        raise NotAllowed("Only the owner or an admin can change this reservation.")
    start_at = aware_utc(start_at, "start_at")
    end_at = aware_utc(end_at, "end_at")
    fresh: list[Lease] | None = None
    if reservation.lease_uuid and start_at < end_at:
        fresh = leases_refresh(start_at=start_at, end_at=end_at)
    moved_lease: tuple[datetime, datetime] | None = None
    try:
        with transaction.atomic():
            locked = Reservation.objects.select_for_update().get(pk=reservation.pk)
            if locked.state not in RESERVATION_ACTIVE_STATES or locked.start_at <= now:
                raise Conflict("Only upcoming reservations can be moved.")
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


def reservation_cancel(
    *, reservation: Reservation, by: User, reason: str = "", ip: str | None = None
) -> Reservation:
    """Cancel a reservation: its resources are free again at once.

    A run booked with it is withdrawn by the runs layer, which calls this in its transaction.
    """
    if reservation.owner_id != by.pk and not _may_book_for_others(by):
        raise NotAllowed("Only the owner or an admin can cancel this reservation.")
    with transaction.atomic():
        locked = Reservation.objects.select_for_update().get(pk=reservation.pk)
        if locked.state not in RESERVATION_ACTIVE_STATES:
            raise Conflict(f"The reservation is already {locked.get_state_display()}.")
        by_admin = by.pk != locked.owner_id
        if by_admin and not reason.strip():
            raise InvalidInput.on_field("reason", "Say why you cancel someone else's reservation.")
        locked.state = ReservationState.CANCELLED
        locked.cancelled_by = by
        locked.cancel_reason = reason
        locked.save(update_fields=["state", "cancelled_by", "cancel_reason", "updated_at"])
        locked.items.update(active=False)
        _release_lease_after_commit(locked)
        audit_record(actor=by, action="reservation.cancel", target=locked, ip=ip, reason=reason)
        if by_admin:
            _notify("cancelled_by_admin", locked.pk)
    logger.info("reservation %s cancelled by %s", reservation.pk, by.get_username())
    return locked


def reservation_decide(
    *,
    reservation: Reservation,
    by: User,
    approve: bool,
    reason: str = "",
    ip: str | None = None,
) -> Reservation:
    """An admin approves or rejects a requested reservation; the owner is told.

    A rejected reservation frees its resources; its run is withdrawn by the runs layer.
    """
    if not by.is_testbed_admin:
        raise NotAllowed("Only admins decide on reservations.")
    if not approve and not reason.strip():
        raise InvalidInput.on_field("reason", "Say why the request is rejected.")
    with transaction.atomic():
        locked = Reservation.objects.select_for_update().get(pk=reservation.pk)
        if locked.state != ReservationState.REQUESTED:
            raise Conflict(
                f"The reservation is {locked.get_state_display()}, not awaiting approval."
            )
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
            audit_record(
                actor=None,
                action="resource.hold",
                target=Resource.objects.get(pk=resource_id),
                reason=reason,
            )
    return bool(held)


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
