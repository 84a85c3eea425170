"""Admins' hands on a mobile node: status, manual drive, emergency stop, daily log, service.

Every command goes to the node's agent through its REST client and into the audit log with
who, when, from where and why — including commands the agent refused.
"""

from __future__ import annotations

from datetime import date
from typing import Any, Final

from django.core.cache import cache
from django.db import transaction

from basestation.client import AgentConflict, AgentError, AgentRejected
from basestation.contract import DIRECTIONS
from bookings.models import Resource
from bookings.rules import velocity_problem
from bookings.services import resource_set_service, robot_event
from core.accounts.models import User
from core.audit.services import audit_record
from core.audit.text import storable_text
from core.cache import database_namespace
from core.errors import Conflict, DomainError, InvalidInput, NotAllowed
from core.live import publish, robot_channel
from portal.runs.agents import agent_client_for

MAX_MANUAL_TTL_S = 10.0
# Hold-to-drive repeats its command a few times a second: one audit entry per hold (and per
# change of velocity or direction), not per repeat. A pause this long starts a new entry.
HOLD_AUDIT_GAP_S = 5.0
# Hold-to-drive: each held command lives this long on the base station and is repeated this
# often. A few repeats' worth, so one slow request does not make the robot stutter; short, so
# a page that vanishes without its stop lets the robot ramp down within a second.
HOLD_TTL_S = 0.6
HOLD_REPEAT_MS = 200


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
    action: str,
    resource: Resource,
    by: User,
    ip: str | None,
    reason: str,
    fn: Any,
    *,
    audit_success: bool = True,
    event: str | None = None,
    **data: Any,
) -> dict[str, Any]:
    """Run one agent call and audit it, whatever the agent answered (a success only when
    ``audit_success``: the repeats of a held command are one action); a success is the
    ``event`` too, if named (``core.events``), in the audit row's transaction."""
    try:
        result: dict[str, Any] = fn()
    except AgentError as exc:
        # A refusal (409/422) and an unreachable agent are both recorded, differently named.
        refused = isinstance(exc, AgentConflict | AgentRejected)
        outcome = {"refused" if refused else "failed": exc.message}
        audit_record(
            actor=by, action=action, target=resource, ip=ip, reason=reason, **outcome, **data
        )
        detail = _conflict_words(exc) or exc.body.get("detail") or exc.message
        if isinstance(exc, AgentConflict):
            raise Conflict(f"The base station refused: {detail}") from exc
        if isinstance(exc, AgentRejected):
            raise InvalidInput(f"The base station refused: {detail}", fields=exc.fields) from exc
        raise AgentUnavailable(
            f"The base station of {resource.name} did not answer: {exc.message}"
        ) from exc
    if audit_success:
        with transaction.atomic():
            audit_record(actor=by, action=action, target=resource, ip=ip, reason=reason, **data)
            if event is not None:
                robot_event(event, resource, reason=reason, by=by)
    return result


# The agent's refusals in the portal's words: its own name its API's paths, which are not the
# console's nor the portal API's.
AGENT_CONFLICT_WORDS: Final = {
    "estop_latched": "the emergency stop is latched: release it first (with a reason)",
}


def _conflict_words(exc: AgentError) -> str | None:
    return AGENT_CONFLICT_WORDS.get(exc.kind or "") if isinstance(exc, AgentConflict) else None


def _hold_repeats(*, resource: Resource, by: User, velocity_mps: float, direction: str) -> bool:
    """Whether this held command repeats the one ``by`` sent last to ``resource`` (the same
    velocity and direction, less than :data:`HOLD_AUDIT_GAP_S` ago)."""
    key = f"robot-hold:{database_namespace()}:{resource.pk}:{by.pk}"
    command = [velocity_mps, direction]
    repeated = cache.get(key) == command
    cache.set(key, command, HOLD_AUDIT_GAP_S)
    return repeated


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
    hold: bool = False,
    ip: str | None = None,
) -> dict[str, Any]:
    """Drive by hand for ``ttl_s`` seconds (dead-man: the agent stops the robot after it).

    ``hold``: one command of hold-to-drive, which the console repeats while the button is
    held; its repeats are audited once (:func:`_hold_repeats`), refusals every time."""
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
    repeat = hold and _hold_repeats(
        resource=resource, by=by, velocity_mps=velocity_mps, direction=direction
    )
    held: dict[str, Any] = {"hold": True} if hold else {}
    answer = _call(
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
        audit_success=not repeat,
        velocity_mps=velocity_mps,
        direction=direction,
        ttl_s=ttl_s,
        force=force,
        **held,
    )
    _publish_motion(resource, answer)
    return answer


def _publish_motion(resource: Resource, answer: dict[str, Any]) -> None:
    """The robot's motion as the drive command's answer read it, to every console watching
    the robot: while a button is held they follow it at the hold's repeat rate (a 2 s status
    poll would show a hold's velocity after it ended). Nothing if the bus is down, or if the
    base station predates motion in its answers."""
    if "robot" in answer:
        publish(
            robot_channel(resource.name),
            {
                "type": "motion",
                "clock": answer.get("clock"),
                "robot": answer["robot"],
                "link": answer.get("link"),
            },
        )


def robot_stop(
    *,
    resource: Resource,
    by: User,
    reason: str,
    ip: str | None = None,
    ignored: list[str] | None = None,
) -> dict[str, Any]:
    """Latch the emergency stop. Any admin may; the reason (any text, any length, or none)
    never blocks it: the audit keeps it whole, the base station its first characters.

    ``ignored`` names what the caller sent besides a reason (audited, never refused)."""
    _admin(by)
    _mobile(resource)
    client = agent_client_for(resource)
    extra: dict[str, Any] = {"ignored": [storable_text(n) for n in ignored]} if ignored else {}
    return _call(
        "robot.stop",
        resource,
        by,
        ip,
        reason,
        lambda: client.stop(user=by.get_username(), reason=reason.strip() or "emergency stop"),
        event="robot.estopped",
        **extra,
    )


def robot_release(
    *, resource: Resource, by: User, reason: str, reopen: bool = False, ip: str | None = None
) -> dict[str, Any]:
    """Release the latched stop; with ``reopen``, put the robot back in service in the same
    step, with the same reason (``resource_set_service``, the console's "Put back in service":
    audited as both). The answer says whether bookings are open: a stop's hold stays until an
    admin lifts it."""
    _admin(by)
    _mobile(resource)
    if not reason.strip():
        raise InvalidInput.on_field("reason", "Say why it is safe to release the stop.")
    client = agent_client_for(resource)
    result = _call(
        "robot.release",
        resource,
        by,
        ip,
        reason,
        lambda: client.release_stop(user=by.get_username()),
        event="robot.estop_released",
    )
    now = Resource.objects.get(pk=resource.pk)
    if reopen and not now.in_service:
        now = resource_set_service(resource=now, by=by, enabled=True, reason=reason, ip=ip)
    return {**result, "in_service": now.in_service, "hold_reason": now.hold_reason}


def robot_day_log(*, resource: Resource, by: User, day: date) -> dict[str, Any]:
    _admin(by)
    _mobile(resource)
    try:
        return agent_client_for(resource).day_log(day)
    except AgentError as exc:
        raise AgentUnavailable(
            f"The base station of {resource.name} did not answer: {exc.message}"
        ) from exc
