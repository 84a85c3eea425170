"""Each robot's health, read from its agent: cached for the pages, and a hold on bookings.

Beat asks every ``HEALTH_POLL_INTERVAL_S`` for each mobile node's ``GET /status``. The answer
(or that the agent did not answer) is cached for the console and the calendar and pushed to
them live. A robot is taken out of booking (``bookings.services.resource_hold``, which the
booking rule "out of service" reads under the booking lock) when its agent reports

- a latched emergency stop,
- a fault (``faults`` in the status: the control loop stopped, the robot not answering),
- a filtered battery voltage under ``HEALTH_LOW_BATTERY_V`` (or its own low-battery flag),

or when the agent has not answered for longer than ``HEALTH_UNREACHABLE_S``. The hold says
why; the admins are e-mailed once; only an admin puts the robot back in service (audited),
and a robot still unhealthy then is held again at the next check.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from typing import Any

from django.conf import settings
from django.core.cache import cache
from django.db.models import QuerySet

from basestation.client import AgentError
from bookings.choices import ResourceKind
from bookings.models import Resource
from bookings.services import resource_hold
from portal.live import hold_publish, publish_on_commit, robot_channel
from portal.runs.agents import agent_client_for

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
    client = agent_client_for(resource)
    # At most one period: a hung agent must not pile checks up behind this one.
    client.timeout_s = min(client.timeout_s, max(1.0, settings.HEALTH_POLL_INTERVAL_S))
    try:
        status = client.status()
    except AgentError as exc:
        since_s = (
            previous.unreachable_since_s
            if previous is not None and previous.unreachable_since_s is not None
            else now_s
        )
        problems = []
        if now_s - since_s >= settings.HEALTH_UNREACHABLE_S:
            problems.append(f"base station unreachable since {_when(since_s)}")
        health = RobotHealth(
            name=resource.name,
            checked_at_s=now_s,
            reachable=False,
            status=previous.status if previous is not None else None,
            error=exc.message,
            unreachable_since_s=since_s,
            problems=problems,
        )
    else:
        health = RobotHealth(
            name=resource.name,
            checked_at_s=now_s,
            reachable=True,
            status=status,
            problems=robot_health_problems(
                status=status, low_battery_v=settings.HEALTH_LOW_BATTERY_V
            ),
        )
    finally:
        client.close()
    try:
        cache.set(_cache_key(resource.name), health, timeout=None)
    except Exception:  # the hold below matters more than the cached copy
        logger.warning("robot health of %s: not cached", resource.name, exc_info=True)
    if health.problems and resource_hold(
        resource_id=resource.pk, reason="; ".join(health.problems)
    ):
        logger.warning("%s taken out of booking: %s", resource.name, "; ".join(health.problems))
        resource.refresh_from_db(fields=["hold_reason", "held_at"])
        hold_publish(resource)
    publish_on_commit(robot_channel(resource.name), {"type": "status", **health.to_json()})
    return health


def robots_held() -> QuerySet[Resource]:
    return Resource.objects.exclude(hold_reason="").order_by("name")


def robots_hold_unnotified() -> QuerySet[Resource]:
    """Holds the admins have not been e-mailed about yet (the sweep queues the mail)."""
    return robots_held().filter(hold_notified_at__isnull=True)
