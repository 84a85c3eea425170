"""Writes for reservations, blackouts and quota policies.

Every check that guards capacity runs inside one transaction under row locks taken in a
fixed order (the user, then the resources by id), so concurrent bookings are decided one at
a time; on PostgreSQL an exclusion constraint backs the overlap check.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from functools import partial
from typing import Any

from django.conf import settings
from django.core.exceptions import ValidationError
from django.db import IntegrityError, transaction
from django.utils import timezone

from bookings.choices import RESERVATION_ACTIVE_STATES, ReservationState, ResourceKind
from bookings.models import Blackout, QuotaPolicy, Reservation, ReservationItem, Resource
from bookings.quotas import quota_violations
from bookings.selectors import first_conflict
from portal.accounts.models import User
from portal.audit.services import audit_record
from portal.errors import Conflict, InvalidInput, NotAllowed
from portal.experiments.choices import RunState
from portal.experiments.models import Experiment, Run
from portal.experiments.services import run_create, run_transition, segments_validate

logger = logging.getLogger(__name__)


class QuotaExceeded(Conflict):
    code = "quota_exceeded"


def _aware(value: datetime, field: str) -> datetime:
    """The instant in UTC: lengths computed from it are real elapsed time, DST or not."""
    if timezone.is_naive(value):
        raise InvalidInput.on_field(field, "Give a time zone (for example 2026-05-01T10:00+01:00).")
    return value.astimezone(UTC)


def _notify(kind: str, reservation_id: int, **extra: Any) -> None:
    from bookings.tasks import reservation_notify

    transaction.on_commit(partial(reservation_notify.delay, kind, reservation_id, **extra))


def _lock(owner: User, resources: Sequence[Resource]) -> None:
    """Serialise bookings per user (quotas) and per resource (overlaps), in a fixed order.

    Whether a resource is in service is read under the lock: taking it out of service while
    someone books it must not let the booking through.
    """
    list(User.objects.select_for_update().filter(pk=owner.pk).values_list("pk"))
    in_service = dict(
        Resource.objects.select_for_update()
        .filter(pk__in=[r.pk for r in resources])
        .order_by("pk")
        .values_list("name", "enabled")
    )
    for name, enabled in sorted(in_service.items()):
        if not enabled:
            raise InvalidInput.on_field("resources", f"{name} is out of service.")


def _validate_window(start_at: datetime, end_at: datetime, now: datetime) -> None:
    if end_at <= start_at:
        raise InvalidInput.on_field("end_at", "The end must be after the start.")
    if start_at < now:
        raise InvalidInput.on_field("start_at", "The start is in the past.")
    max_length = timedelta(seconds=settings.RESERVATION_MAX_S)
    if end_at - start_at > max_length:
        raise InvalidInput.on_field(
            "end_at", f"A reservation lasts at most {max_length.total_seconds() / 3600:g} h."
        )


def _validate_program(
    resources: Sequence[Resource],
    experiment: Experiment | None,
    owner: User,
    start_at: datetime,
    end_at: datetime,
) -> Resource | None:
    """The mobile node that runs ``experiment``, after checking the program fits it."""
    mobiles = [r for r in resources if r.kind == ResourceKind.MOBILE]
    if len(mobiles) > 1:
        raise InvalidInput.on_field("resources", "Book one mobile node per reservation.")
    if not mobiles:
        if experiment is not None:
            raise InvalidInput.on_field("experiment", "Only mobile nodes run experiments.")
        return None
    mobile = mobiles[0]
    if experiment is None:
        raise InvalidInput.on_field("experiment", "Choose the experiment the robot will run.")
    if experiment.owner_id != owner.pk:
        raise NotAllowed.on_field("experiment", "That experiment belongs to someone else.")
    segments_validate(experiment.segments, max_velocity_mps=mobile.max_velocity_mps)
    length_s = (end_at - start_at).total_seconds()
    if experiment.duration_s > length_s:
        raise InvalidInput.on_field(
            "end_at",
            f"The experiment lasts {experiment.duration_s:g} s but the reservation only "
            f"{length_s:g} s.",
        )
    return mobile


def _check_capacity(
    *,
    owner: User,
    resources: Sequence[Resource],
    start_at: datetime,
    end_at: datetime,
    now: datetime,
    exclude_id: int | None,
    override_reason: str,
) -> list[str]:
    """Blackouts and overlaps always; quotas unless overridden. Returns what was overridden."""
    local = timezone.localtime
    conflict = first_conflict(
        resources=resources, start_at=start_at, end_at=end_at, exclude_reservation_id=exclude_id
    )
    if conflict is not None:
        since = f"{local(conflict['start_at']):%Y-%m-%d %H:%M}"
        until = f"{local(conflict['end_at']):%Y-%m-%d %H:%M}"
        if conflict["kind"] == "blackout":
            raise Conflict.on_field(
                "start_at",
                f"Maintenance “{conflict['label']}” from {since} to {until}: "
                "nothing can be booked then.",
            )
        raise Conflict.on_field(
            "start_at", f"{conflict['label']} is already booked from {since} to {until}."
        )
    problems = quota_violations(
        user=owner,
        resources=resources,
        start_at=start_at,
        end_at=end_at,
        now=now,
        exclude_id=exclude_id,
    )
    if problems and not override_reason:
        raise QuotaExceeded(problems[0], fields={"quota": problems})
    return problems


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
) -> Reservation:
    """Book ``resources`` for ``[start_at, end_at)``; on a mobile node, also schedule the run.

    ``by`` is who acts (an admin booking for ``owner``; defaults to ``owner``). Only an admin
    may pass ``override_reason``, which lets the booking past quota rules (never past another
    booking or a maintenance window) and is recorded in the audit log.
    """
    now = now or timezone.now()
    by = by or owner
    resources = list(resources or ([resource] if resource is not None else []))
    if not resources:
        raise InvalidInput.on_field("resources", "Choose at least one resource.")
    if len({r.pk for r in resources}) != len(resources):
        raise InvalidInput.on_field("resources", "A resource is listed twice.")
    if by.pk != owner.pk and not by.is_testbed_admin:
        raise NotAllowed("Only admins book for someone else.")
    override_reason = override_reason.strip()
    if override_reason and not by.is_testbed_admin:
        raise NotAllowed.on_field("override_reason", "Only admins can override quotas.")
    start_at = _aware(start_at, "start_at")
    end_at = _aware(end_at, "end_at")
    _validate_window(start_at, end_at, now)
    for r in resources:
        if not r.enabled:
            raise InvalidInput.on_field("resources", f"{r.name} is out of service.")
    mobile = _validate_program(resources, experiment, owner, start_at, end_at)
    needs_approval = any(r.requires_approval for r in resources) and not by.is_testbed_admin
    state = ReservationState.REQUESTED if needs_approval else ReservationState.CONFIRMED

    try:
        with transaction.atomic():
            _lock(owner, resources)
            overridden = _check_capacity(
                owner=owner,
                resources=resources,
                start_at=start_at,
                end_at=end_at,
                now=now,
                exclude_id=None,
                override_reason=override_reason,
            )
            reservation = Reservation(
                owner=owner,
                start_at=start_at,
                end_at=end_at,
                state=state,
                title=title or (experiment.title if experiment else ""),
                override_reason=override_reason if overridden else "",
            )
            # The window was checked above and the database enforces the constraint again;
            # re-running it here would only cost three more round trips under the lock.
            reservation.full_clean(exclude=["owner"], validate_constraints=False)
            reservation.save()
            ReservationItem.objects.bulk_create(
                ReservationItem(
                    reservation=reservation, resource=r, start_at=start_at, end_at=end_at
                )
                for r in resources
            )
            if mobile is not None and experiment is not None:
                run_create(reservation=reservation, resource=mobile, experiment=experiment)
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
        # The exclusion constraint caught an overlap the locked check could not see
        # (only possible if something wrote around the services).
        raise Conflict.on_field("start_at", "That slot was just taken.") from exc
    logger.info("reservation %s (%s) created by %s", reservation.pk, state, by.get_username())
    return reservation


def reservation_reschedule(
    *,
    reservation: Reservation,
    by: User,
    start_at: datetime,
    end_at: datetime,
    ip: str | None = None,
    now: datetime | None = None,
) -> Reservation:
    """Move an upcoming reservation (every check again, itself excluded)."""
    now = now or timezone.now()
    if reservation.owner_id != by.pk and not by.is_testbed_admin:
        raise NotAllowed("Only the owner or an admin can change this reservation.")
    start_at = _aware(start_at, "start_at")
    end_at = _aware(end_at, "end_at")
    _validate_window(start_at, end_at, now)
    with transaction.atomic():
        locked = Reservation.objects.select_for_update().get(pk=reservation.pk)
        if locked.state not in RESERVATION_ACTIVE_STATES or locked.start_at <= now:
            raise Conflict("Only upcoming reservations can be moved.")
        resources = list(locked.resources.all())
        run = Run.objects.filter(reservation=locked).select_related("experiment").first()
        if run is not None:
            if run.state != RunState.SCHEDULED:
                raise Conflict("Its run is already on the base station; cancel and book again.")
            _validate_program(resources, run.experiment, locked.owner, start_at, end_at)
        _lock(locked.owner, resources)
        _check_capacity(
            owner=locked.owner,
            resources=resources,
            start_at=start_at,
            end_at=end_at,
            now=now,
            exclude_id=locked.pk,
            override_reason=locked.override_reason,
        )
        before = (locked.start_at.isoformat(), locked.end_at.isoformat())
        locked.start_at, locked.end_at = start_at, end_at
        locked.full_clean()
        locked.save(update_fields=["start_at", "end_at", "updated_at"])
        locked.items.update(start_at=start_at, end_at=end_at)
        if run is not None:
            Run.objects.filter(pk=run.pk).update(start_at=start_at, end_at=end_at)
        audit_record(
            actor=by,
            action="reservation.reschedule",
            target=locked,
            ip=ip,
            before=before,
            after=(start_at.isoformat(), end_at.isoformat()),
        )
    return locked


def _release(reservation: Reservation, state: str, why: str) -> None:
    """End a reservation's hold on its resources and withdraw its run."""
    from bookings.tasks import run_unstage

    reservation.items.update(active=False)
    run = Run.objects.filter(reservation=reservation).first()
    if run is None or run_transition(
        run_id=run.pk, from_states=[RunState.SCHEDULED], to_state=RunState.CANCELLED, reason=why
    ):
        return
    if run.state in (RunState.STAGED, RunState.RUNNING):
        # The agent decides: a staged run is cancelled there, a running one is aborted
        # (the robot ramps to zero) and its data collected as an interrupted run.
        transaction.on_commit(partial(run_unstage.delay, run.pk))


def reservation_cancel(
    *, reservation: Reservation, by: User, reason: str = "", ip: str | None = None
) -> Reservation:
    """Cancel a reservation and its run; a staged or running run is withdrawn from its agent."""
    if reservation.owner_id != by.pk and not by.is_testbed_admin:
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
        _release(locked, ReservationState.CANCELLED, reason or f"cancelled by {by.get_username()}")
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
    """An admin approves or rejects a requested reservation; the owner is told."""
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
            _release(locked, ReservationState.REJECTED, f"request rejected: {reason}")
        audit_record(
            actor=by,
            action="reservation.approve" if approve else "reservation.reject",
            target=locked,
            ip=ip,
            reason=reason,
        )
        _notify("approved" if approve else "rejected", locked.pk)
    return locked


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
    start_at = _aware(start_at, "start_at")
    end_at = _aware(end_at, "end_at")
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
        items = ReservationItem.objects.filter(
            active=True, start_at__lt=end_at, end_at__gt=start_at
        )
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


def testbed_resources_ensure(spec: TestbedSpec) -> list[str]:
    """Create whichever of the spec's resources do not exist yet; returns their names.

    Existing ones are left untouched (an admin may have changed them since). Everything is
    checked before anything is written.
    """
    if not 1 <= spec.fixed_nodes <= 200:
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
            description="Rail robot around the roof of IT building 1",
            agent_url=spec.agent_url,
            max_velocity_mps=spec.max_velocity_mps,
            max_accel_mps2=spec.max_accel_mps2,
        ),
        *(
            Resource(name=f"node-{i:02d}", kind=ResourceKind.FIXED, description=f"Fixed node {i}")
            for i in range(1, spec.fixed_nodes + 1)
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
