"""Writes for resources: in and out of service, the health check's holds, and what the
health check learns of a robot's agent (whether it answers, the limits it reports).

Taking a resource in or out of service takes the row lock bookings take, so no booking is
half-way through while it changes.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime

from django.db import transaction
from django.utils import timezone

from bookings.models import HOLD_REASON_MAX_CHARS, Resource
from core.accounts.models import User
from core.audit.services import audit_record
from core.audit.text import storable_text
from core.errors import InvalidInput, NotAllowed
from core.events.services import event_record


def robot_event(type: str, resource: Resource, *, reason: str, by: User | None) -> None:
    """A robot's change as an event for staff (``core.events``), in the change's transaction."""
    event_record(
        subject=f"robot:{resource.name}",
        type=type,
        owner_id=None,
        payload={
            "resource": resource.name,
            "reason": storable_text(reason),
            "by": by.get_username() if by is not None else None,
        },
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
            locked.hold_reason, locked.held_at = "", None
        locked.save(update_fields=["enabled", "hold_reason", "held_at"])
        audit_record(
            actor=by,
            action="resource.in_service" if enabled else "resource.out_of_service",
            target=locked,
            ip=ip,
            reason=reason,
            **({"lifted_hold": lifted} if lifted else {}),
        )
        if lifted:
            robot_event("robot.released", locked, reason=reason, by=by)
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
        )
        if held:
            resource = Resource.objects.get(pk=resource_id)
            audit_record(actor=None, action="resource.hold", target=resource, reason=reason)
            # Counted by its handler (bookings.handlers), as every reaction to an event.
            robot_event("robot.held", resource, reason=reason, by=None)
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
        locked.hold_reason, locked.held_at = "", None
        locked.save(update_fields=["hold_reason", "held_at"])
        audit_record(
            actor=None, action="resource.hold_lifted", target=locked, reason=why, lifted_hold=lifted
        )
        robot_event("robot.released", locked, reason=why, by=None)
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
