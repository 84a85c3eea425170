"""Admins' hands on a mobile node: status, manual drive, emergency stop, daily log, service.

Every command goes to the node's agent through its REST client and into the audit log with
who, when, from where and why — including commands the agent refused.
"""

from __future__ import annotations

from datetime import date
from typing import Any

from basestation.client import AgentConflict, AgentError, AgentRejected
from basestation.contract import DIRECTIONS
from bookings.models import Resource
from bookings.rules import velocity_problem
from core.accounts.models import User
from core.audit.services import audit_record
from core.errors import Conflict, DomainError, InvalidInput, NotAllowed
from portal.runs.agents import agent_client_for

MAX_MANUAL_TTL_S = 10.0


class AgentUnavailable(DomainError):
    http_status = 503
    code = "agent_unavailable"


def _admin(by: User) -> None:
    if not by.is_testbed_admin:
        raise NotAllowed("Only admins command the robot.")


def _mobile(resource: Resource) -> None:
    if not resource.is_mobile:
        raise InvalidInput.on_field("resource", f"{resource.name} is not a mobile node.")


def _call(
    action: str, resource: Resource, by: User, ip: str | None, reason: str, fn: Any, **data: Any
) -> dict[str, Any]:
    """Run one agent call and audit it, whatever the agent answered."""
    try:
        result: dict[str, Any] = fn()
    except AgentError as exc:
        # A refusal (409/422) and an unreachable agent are both recorded, differently named.
        refused = isinstance(exc, AgentConflict | AgentRejected)
        outcome = {"refused" if refused else "failed": exc.message}
        audit_record(
            actor=by, action=action, target=resource, ip=ip, reason=reason, **outcome, **data
        )
        detail = exc.body.get("detail") or exc.message
        if isinstance(exc, AgentConflict):
            raise Conflict(f"The base station refused: {detail}") from exc
        if isinstance(exc, AgentRejected):
            raise InvalidInput(f"The base station refused: {detail}", fields=exc.fields) from exc
        raise AgentUnavailable(
            f"The base station of {resource.name} did not answer: {exc.message}"
        ) from exc
    audit_record(actor=by, action=action, target=resource, ip=ip, reason=reason, **data)
    return result


def robot_status(*, resource: Resource) -> dict[str, Any]:
    _mobile(resource)
    client = agent_client_for(resource)
    try:
        return {"status": client.status(), "battery": client.battery()}
    except AgentError as exc:
        raise AgentUnavailable(
            f"The base station of {resource.name} did not answer: {exc.message}"
        ) from exc


def robot_drive(
    *,
    resource: Resource,
    by: User,
    velocity_mps: float,
    direction: str,
    ttl_s: float,
    reason: str,
    force: bool = False,
    ip: str | None = None,
) -> dict[str, Any]:
    """Drive by hand for ``ttl_s`` seconds (dead-man: the agent stops the robot after it)."""
    _admin(by)
    _mobile(resource)
    if not reason.strip():
        raise InvalidInput.on_field("reason", "Say why you drive the robot by hand.")
    if direction not in DIRECTIONS:
        raise InvalidInput.on_field("direction", "Direction is cw or ccw.")
    why = velocity_problem(resource=resource, velocity_mps=velocity_mps)
    if why is not None:
        raise InvalidInput.on_field("velocity_mps", why[0].upper() + why[1:])
    if not 0 < ttl_s <= MAX_MANUAL_TTL_S:
        raise InvalidInput.on_field("ttl_s", f"Hold a command for at most {MAX_MANUAL_TTL_S:g} s.")
    client = agent_client_for(resource)
    return _call(
        "robot.control",
        resource,
        by,
        ip,
        reason,
        lambda: client.control(
            user=by.get_username(),
            velocity_mps=velocity_mps,
            direction=direction,
            ttl_s=ttl_s,
            force=force,
        ),
        velocity_mps=velocity_mps,
        direction=direction,
        ttl_s=ttl_s,
        force=force,
    )


def robot_stop(
    *, resource: Resource, by: User, reason: str, ip: str | None = None
) -> dict[str, Any]:
    """Latch the emergency stop. Anyone admin may; a reason is asked for but never blocks it."""
    _admin(by)
    _mobile(resource)
    client = agent_client_for(resource)
    return _call(
        "robot.stop",
        resource,
        by,
        ip,
        reason,
        lambda: client.stop(user=by.get_username(), reason=reason or "emergency stop"),
    )


def robot_release(
    *, resource: Resource, by: User, reason: str, ip: str | None = None
) -> dict[str, Any]:
    _admin(by)
    _mobile(resource)
    if not reason.strip():
        raise InvalidInput.on_field("reason", "Say why it is safe to release the stop.")
    client = agent_client_for(resource)
    return _call(
        "robot.release",
        resource,
        by,
        ip,
        reason,
        lambda: client.release_stop(user=by.get_username()),
    )


def robot_day_log(*, resource: Resource, by: User, day: date) -> dict[str, Any]:
    _admin(by)
    _mobile(resource)
    try:
        return agent_client_for(resource).day_log(day)
    except AgentError as exc:
        raise AgentUnavailable(
            f"The base station of {resource.name} did not answer: {exc.message}"
        ) from exc
