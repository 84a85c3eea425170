"""Every event type, its version and the shape of its payload (JSON Schema).

A reservation's and a run's events belong to the reservation's owner; a robot's and the
scheduler link's to no one (staff read them).

The one list: ``services.event_record`` refuses a type or a payload that is not here, the
OpenAPI schema documents these (``GET /api/v1/events/``), and the tests hold every payload
written to its schema. A payload changes shape only under a new version.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

_TIME = {"type": "string", "format": "date-time"}
_DOORS = ["web", "api", "cli", "lease_api", "admin", ""]

RESERVATION_V1: dict[str, Any] = {
    "type": "object",
    "properties": {
        "reservation": {"type": "integer"},
        "state": {
            "type": "string",
            "enum": ["requested", "confirmed", "rejected", "cancelled", "completed"],
        },
        "resources": {"type": "array", "items": {"type": "string"}},
        "start_at": _TIME,
        "end_at": _TIME,
        "title": {"type": "string"},
        "via": {"type": "string", "enum": _DOORS, "description": "the door it came through"},
        "by": {"type": ["string", "null"], "description": "who made the change"},
    },
    "required": ["reservation", "state", "resources", "start_at", "end_at", "via", "by"],
    "additionalProperties": False,
}

RUN_STATES = [
    "scheduled",
    "staged",
    "running",
    "collecting",
    "completed",
    "cancelled",
    "failed",
    "interrupted",
]

RUN_V1: dict[str, Any] = {
    "type": "object",
    "properties": {
        "run": {"type": "integer"},
        "reservation": {"type": "integer"},
        "resource": {"type": "string"},
        "state": {"type": "string", "enum": RUN_STATES},
        "from_state": {"type": ["string", "null"], "enum": [*RUN_STATES, None]},
        "reason": {"type": "string"},
        "cause": {"type": "string"},
    },
    "required": ["run", "reservation", "resource", "state", "from_state", "reason", "cause"],
    "additionalProperties": False,
}


ROBOT_V1: dict[str, Any] = {
    "type": "object",
    "properties": {
        "resource": {"type": "string"},
        "reason": {"type": "string"},
        "by": {"type": ["string", "null"], "description": "the admin; none for the system"},
    },
    "required": ["resource", "reason", "by"],
    "additionalProperties": False,
}

SCHEDULER_LINK_V1: dict[str, Any] = {
    "type": "object",
    "properties": {
        "error": {"type": "string", "description": "what failed (empty when up again)"},
        "since": {**_TIME, "description": "the last success before it went down, or none"},
    },
    "required": ["error"],
    "additionalProperties": False,
}


@dataclass(frozen=True)
class EventType:
    name: str
    version: int
    description: str
    payload: dict[str, Any]
    # The payload's schema as the OpenAPI description names it (core/openapi.py).
    component: str


_RESERVATION_TYPES = {
    "reservation.created": "A reservation was made (confirmed, or requested when it waits for "
    "an admin).",
    "reservation.moved": "A reservation was moved to another time.",
    "reservation.approved": "An admin confirmed a requested reservation.",
    "reservation.rejected": "An admin rejected a requested reservation.",
    "reservation.cancelled": "A reservation was cancelled (its run with it).",
}
_RUN_TYPES = {f"run.{state}": f"A run is now {state}." for state in RUN_STATES}

_ROBOT_TYPES = {
    "robot.held": "The health check took a robot out of booking.",
    "robot.released": "A robot's hold was lifted: it can be booked again.",
    "robot.estopped": "An admin latched a robot's emergency stop.",
    "robot.estop_released": "An admin released a robot's emergency stop.",
}
_SCHEDULER_TYPES = {
    "scheduler.link_down": "The portal cannot reach the testbed scheduler.",
    "scheduler.link_up": "The portal reaches the testbed scheduler again.",
}

# Each payload shape and version, as a component of the OpenAPI description, with its types.
PAYLOADS: dict[str, tuple[dict[str, Any], dict[str, str]]] = {
    "ReservationEventV1": (RESERVATION_V1, _RESERVATION_TYPES),
    "RunEventV1": (RUN_V1, _RUN_TYPES),
    "RobotEventV1": (ROBOT_V1, _ROBOT_TYPES),
    "SchedulerLinkEventV1": (SCHEDULER_LINK_V1, _SCHEDULER_TYPES),
}

EVENT_TYPES: dict[str, EventType] = {
    name: EventType(name, 1, text, payload, component)
    for component, (payload, types) in PAYLOADS.items()
    for name, text in types.items()
}
