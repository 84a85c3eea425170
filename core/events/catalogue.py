"""Every event type, its version and the shape of its payload (JSON Schema).

A reservation's and a run's events belong to the reservation's owner, a webhook's to its
owner; a robot's and the scheduler link's to no one (staff read them).

The one list: ``services.event_record`` refuses a type or a payload that is not here, the
OpenAPI schema documents these (``GET /api/v1/events/``), and the tests hold every payload
written to its schema. A payload changes shape only under a new version.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

_TIME = {"type": "string", "format": "date-time"}
_DOORS = ["web", "api", "cli", "lease_api", "admin", "queue", ""]

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

RESERVATION_FLAGGED_V1: dict[str, Any] = {
    "type": "object",
    "properties": {
        "reservation": {"type": "integer"},
        "state": RESERVATION_V1["properties"]["state"],
        "resources": {"type": "array", "items": {"type": "string"}},
        "start_at": _TIME,
        "end_at": _TIME,
        "title": {"type": "string"},
        "problem": {
            "type": "string",
            "enum": ["maintenance", "lease_conflict", "lease_vanished"],
            "description": "a maintenance window over it, a lease made on the testbed "
            "scheduler over it, or its own lease gone from the scheduler",
        },
        "note": {"type": "string", "description": "what the owner and the admins are told"},
        "blackout": {"type": ["integer", "null"], "description": "the maintenance window"},
    },
    "required": [
        "reservation",
        "state",
        "resources",
        "start_at",
        "end_at",
        "title",
        "problem",
        "note",
        "blackout",
    ],
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

RUN_DATA_V1: dict[str, Any] = {
    "type": "object",
    "properties": {
        "run": {"type": "integer"},
        "reservation": {"type": "integer"},
        "resource": {"type": "string"},
        "state": {"type": "string", "enum": ["completed", "interrupted", "failed", "cancelled"]},
        "samples": {"type": "integer", "minimum": 1, "description": "how many were collected"},
        "missing": {
            "type": "integer",
            "minimum": 0,
            "description": "how many stretches of the program have no samples",
        },
        "files": {
            "type": "object",
            "description": "where to fetch them (paths on the portal)",
            "properties": {
                "csv": {"type": "string"},
                "json": {"type": "string"},
                "analysis": {"type": "string"},
            },
            "required": ["csv", "json", "analysis"],
            "additionalProperties": False,
        },
    },
    "required": ["run", "reservation", "resource", "state", "samples", "missing", "files"],
    "additionalProperties": False,
}

RUN_MEASURED_V1: dict[str, Any] = {
    "type": "object",
    "properties": {
        "run": {"type": "integer"},
        "reservation": {"type": "integer"},
        "resource": {"type": "string"},
        "series": {"type": "string", "description": "the series's name"},
        "change": {
            "type": "string",
            "enum": ["added", "placed", "deleted"],
            "description": "points added (a file or a batch), placed again (a new clock offset "
            "or marker), or the series deleted",
        },
        "points": {"type": "integer", "minimum": 0, "description": "the series's points now"},
        "stored": {"type": "integer", "minimum": 0, "description": "values this change stored"},
        "via": {"type": "string", "enum": _DOORS, "description": "the door it came through"},
    },
    "required": ["run", "reservation", "resource", "series", "change", "points", "stored", "via"],
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

WEBHOOK_V1: dict[str, Any] = {
    "type": "object",
    "properties": {
        "webhook": {"type": "integer"},
        "url": {"type": "string"},
        "reason": {"type": "string", "description": "why it was paused (empty for a test)"},
    },
    "required": ["webhook", "url", "reason"],
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
    "reservation.starting_soon": "A confirmed reservation starts within the reminder lead "
    "(RESERVATION_REMINDER_LEAD_S); once per reservation.",
}
_RESERVATION_FLAGGED_TYPES = {
    "reservation.flagged": "Something stands in a reservation's way: a maintenance window, or "
    "a lease on the testbed scheduler. Once per cause.",
}
_RUN_TYPES = {f"run.{state}": f"A run is now {state}." for state in RUN_STATES}
_RUN_DATA_TYPES = {
    "run.data_ready": "A run has ended and its samples are stored, complete or with the "
    "stretches it lacks counted: they can be fetched. Once per run, after its last state.",
}
_RUN_MEASURED_TYPES = {
    "run.measured": "A run's measurement series changed: points added (uploaded after the run "
    "or pushed during it), placed again on a new clock offset, or the series deleted.",
}

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
_WEBHOOK_TYPES = {
    "webhook.test": "Sent on its owner's request to one webhook only, to try it.",
    "webhook.paused": "A webhook failed for its whole retry window and was paused: nothing is "
    "sent to it until its owner resumes it.",
}

QUEUE_REQUEST_V1: dict[str, Any] = {
    "type": "object",
    "properties": {
        "request": {"type": "integer", "description": "the queued request"},
        "state": {"type": "string", "enum": ["waiting", "booked", "expired", "cancelled"]},
        "robot": {"type": "string"},
        "title": {"type": "string"},
        "earliest_at": _TIME,
        "latest_end_at": _TIME,
        "reservation": {
            "type": ["integer", "null"],
            "description": "the reservation the queue made (booked only)",
        },
        "reason": {"type": "string", "description": "why it expired or was withdrawn"},
    },
    "required": [
        "request",
        "state",
        "robot",
        "title",
        "earliest_at",
        "latest_end_at",
        "reservation",
        "reason",
    ],
    "additionalProperties": False,
}
_QUEUE_TYPES = {
    "queue.booked": "The queue booked a request in the first slot that fitted (the same change "
    "records its reservation.created).",
    "queue.expired": "A queued request could not be booked before its latest end; the reason "
    "says what held it back.",
    "queue.cancelled": "A waiting request was withdrawn.",
}
CAMPAIGN_V1: dict[str, Any] = {
    "type": "object",
    "properties": {
        "campaign": {"type": "integer"},
        "title": {"type": "string"},
        "state": {"type": "string", "enum": ["active", "paused", "cancelled"]},
        "robot": {"type": "string"},
        "runs": {"type": "integer", "minimum": 1, "description": "the campaign's runs"},
        "ended": {
            "type": "object",
            "description": "how many runs ended how: a run's end state (completed, failed, "
            "interrupted, cancelled) or the queue's (expired, cancelled before booking)",
            "additionalProperties": {"type": "integer", "minimum": 1},
        },
    },
    "required": ["campaign", "title", "state", "robot", "runs", "ended"],
    "additionalProperties": False,
}
_CAMPAIGN_TYPES = {
    "campaign.done": "Every run of a campaign has ended (completed, failed, expired or "
    "withdrawn): its results and download are final. Once per campaign.",
}

# Each payload shape and version, as a component of the OpenAPI description, with its types.
PAYLOADS: dict[str, tuple[dict[str, Any], dict[str, str]]] = {
    "ReservationEventV1": (RESERVATION_V1, _RESERVATION_TYPES),
    "ReservationFlaggedEventV1": (RESERVATION_FLAGGED_V1, _RESERVATION_FLAGGED_TYPES),
    "RunEventV1": (RUN_V1, _RUN_TYPES),
    "RunDataEventV1": (RUN_DATA_V1, _RUN_DATA_TYPES),
    "RunMeasuredEventV1": (RUN_MEASURED_V1, _RUN_MEASURED_TYPES),
    "RobotEventV1": (ROBOT_V1, _ROBOT_TYPES),
    "SchedulerLinkEventV1": (SCHEDULER_LINK_V1, _SCHEDULER_TYPES),
    "WebhookEventV1": (WEBHOOK_V1, _WEBHOOK_TYPES),
    "QueueRequestEventV1": (QUEUE_REQUEST_V1, _QUEUE_TYPES),
    "CampaignEventV1": (CAMPAIGN_V1, _CAMPAIGN_TYPES),
}

# Types that happen at most once to a subject (a unique index holds it: ``Event``).
ONCE_PER_SUBJECT = ["reservation.starting_soon", "run.data_ready"]

EVENT_TYPES: dict[str, EventType] = {
    name: EventType(name, 1, text, payload, component)
    for component, (payload, types) in PAYLOADS.items()
    for name, text in types.items()
}
