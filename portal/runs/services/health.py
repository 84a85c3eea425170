"""Each robot's health, read from its agent: cached for the pages, and a hold on bookings.

Beat asks every ``HEALTH_POLL_INTERVAL_S`` for each mobile node's ``GET /status``. The answer
(or that the agent did not answer) is cached for the console and the calendar and pushed to
them live. A robot is taken out of booking (``resource_hold`` in
``bookings/services/resources.py``, which the booking rule "out of service" reads under the
booking lock) when its agent reports

- a latched emergency stop,
- a fault (``faults`` in the status: the control loop stopped, the robot not answering),
- a filtered battery voltage under ``HEALTH_LOW_BATTERY_V`` (or its own low-battery flag),

or when the agent has not answered for longer than ``HEALTH_UNREACHABLE_S`` (counted from the
first failed check, kept on the resource so that a cache restart does not reset it), or when
the portal has no token for it ("agent not configured": a robot of an earlier set-up). The
hold says why; the admins are e-mailed once; only an admin puts the robot back in service (audited),
and a robot still unhealthy then is held again at the next check.

Each answer's ``limits`` (the agent's effective velocity and acceleration limits and the
robot's hard maximum) are recorded on the resource: booking checks programs against the
stricter of them and the resource's own limit (``bookings.rules.velocity_limit``).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Any

from django.conf import settings
from django.core.cache import cache
from django.db.models import QuerySet

from basestation.client import AgentClient, AgentError
from bookings.choices import ResourceKind
from bookings.models import Resource
from bookings.services import (
    AGENT_NOT_CONFIGURED,
    AgentLimits,
    resource_agent_reachable,
    resource_agent_unreachable,
    resource_hold,
    resource_record_agent_limits,
)
from core.live import publish_on_commit, robot_channel
from portal.runs.agents import AgentNotConfigured, agent_client_for

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RobotHealth:
    """One check of a robot: what its agent said (the last status it gave, if it did not
    answer this time), and what is wrong."""

    name: str
    checked_at_s: float
    reachable: bool
    status: dict[str, Any] | None = None
    error: str = ""
    # Since when the agent has not answered, across checks; None while it answers.
    unreachable_since_s: float | None = None
    problems: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def _cache_key(name: str) -> str:
    return f"robot-health:{name}"


def robot_health_cached(*, name: str) -> RobotHealth | None:
    """The last check of ``name`` (None if there was none, or the cache cannot say)."""
    try:
        cached = cache.get(_cache_key(name))
    except Exception:  # any cache failure: the pages then show no status rather than fail
        logger.warning("robot health of %s: cache unavailable", name, exc_info=True)
        return None
    return cached if isinstance(cached, RobotHealth) else None


def robots_to_check() -> QuerySet[Resource]:
    """Mobile nodes with an agent. One an admin took out of service is still read (its
    console shows it while it is driven by hand for maintenance), but never held."""
    return Resource.objects.filter(kind=ResourceKind.MOBILE).exclude(agent_url="")


def robot_health_problems(*, status: dict[str, Any], low_battery_v: float) -> list[str]:
    """What in an agent's status makes its robot unfit to book, in words for people."""
    problems = []
    estop = status.get("estop")
    if isinstance(estop, dict) and estop.get("latched"):
        why = estop.get("reason")
        problems.append("emergency stop latched" + (f": {why}" if why else ""))
    faults = status.get("faults")
    if isinstance(faults, list):
        problems += [f"fault: {fault}" for fault in faults if isinstance(fault, str)]
    battery = status.get("battery")
    battery = battery if isinstance(battery, dict) else {}
    filtered_v = battery.get("filtered_v")
    if (
        isinstance(filtered_v, int | float)
        and not isinstance(filtered_v, bool)
        and low_battery_v > 0
        and filtered_v < low_battery_v
    ):
        problems.append(f"battery low: {filtered_v:.1f} V, under {low_battery_v:g} V")
    elif battery.get("low") is True:
        problems.append("battery low (the base station's own threshold)")
    return problems


def _positive(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) and value > 0 else None


def agent_limits(status: dict[str, Any]) -> AgentLimits | None:
    """The ``limits`` of an agent's status; None when it has none (an agent older than
    them) or they are not positive numbers."""
    limits = status.get("limits")
    if not isinstance(limits, dict):
        return None
    velocity = _positive(limits.get("max_velocity_mps"))
    accel = _positive(limits.get("max_accel_mps2"))
    if velocity is None or accel is None:
        return None
    return AgentLimits(
        max_velocity_mps=velocity,
        max_accel_mps2=accel,
        robot_hard_max_velocity_mps=_positive(limits.get("robot_hard_max_velocity_mps")),
    )


def _when(at_s: float) -> str:
    return datetime.fromtimestamp(at_s, UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def robot_health_check(*, resource_id: int, now_s: float | None = None) -> RobotHealth | None:
    """Read one robot's status from its agent, cache it, push it, and hold the robot if it
    is unfit (unless an admin took it out of service already). None if the resource is gone
    or has no agent."""
    resource = robots_to_check().filter(pk=resource_id).first()
    if resource is None:
        return None
    now_s = time.time() if now_s is None else now_s
    previous = robot_health_cached(name=resource.name)
    try:
        client = agent_client_for(resource)
    except AgentNotConfigured as exc:
        # Nothing can reach its agent, so nothing could run on it: out of booking, with the
        # reason, once (the hold is made once; a check of it is no error to log again).
        health = RobotHealth(
            name=resource.name,
            checked_at_s=now_s,
            reachable=False,
            status=previous.status if previous is not None else None,
            error=str(exc),
            problems=[f"{AGENT_NOT_CONFIGURED}: {exc.why}"],
        )
    else:
        health = _ask_agent(resource, client, previous=previous, now_s=now_s)
    try:
        cache.set(_cache_key(resource.name), health, timeout=None)
    except Exception:  # the hold below matters more than the cached copy
        logger.warning("robot health of %s: not cached", resource.name, exc_info=True)
    if health.problems and resource_hold(
        resource_id=resource.pk, reason="; ".join(health.problems)
    ):
        # Its robot.held event tells the pages (portal/web/handlers.py) and the admins.
        logger.warning("%s taken out of booking: %s", resource.name, "; ".join(health.problems))
    publish_on_commit(robot_channel(resource.name), {"type": "status", **health.to_json()})
    return health


def _ask_agent(
    resource: Resource, client: AgentClient, *, previous: RobotHealth | None, now_s: float
) -> RobotHealth:
    # At most one period: a hung agent must not pile checks up behind this one.
    client.timeout_s = min(client.timeout_s, max(1.0, settings.HEALTH_POLL_INTERVAL_S))
    try:
        status = client.status()
    except AgentError as exc:
        # Counted in the database: a cache restarted meanwhile does not start it again.
        now = datetime.fromtimestamp(now_s, UTC)
        since = resource_agent_unreachable(resource_id=resource.pk, at=now)
        since_s = since.timestamp()
        problems = []
        # In whole microseconds, as stored: a float difference could fall short by a hair.
        if now - since >= timedelta(seconds=settings.HEALTH_UNREACHABLE_S):
            problems.append(f"base station unreachable since {_when(since_s)}")
        return RobotHealth(
            name=resource.name,
            checked_at_s=now_s,
            reachable=False,
            status=previous.status if previous is not None else None,
            error=exc.message,
            unreachable_since_s=since_s,
            problems=problems,
        )
    finally:
        client.close()
    if resource.agent_unreachable_since is not None:
        resource_agent_reachable(resource_id=resource.pk)
    limits = agent_limits(status)
    if limits is not None and resource_record_agent_limits(resource_id=resource.pk, limits=limits):
        logger.info("%s: its agent reports %s", resource.name, limits)
    return RobotHealth(
        name=resource.name,
        checked_at_s=now_s,
        reachable=True,
        status=status,
        problems=robot_health_problems(status=status, low_battery_v=settings.HEALTH_LOW_BATTERY_V),
    )


def robots_held() -> QuerySet[Resource]:
    return Resource.objects.exclude(hold_reason="").order_by("name")
