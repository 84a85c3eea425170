"""A queued request's changes as events (``core.events``), in the change's transaction."""

from __future__ import annotations

from core.events.services import event_record
from portal.queue.models import QueueRequest


def queue_request_event_record(type: str, request: QueueRequest) -> None:
    """The request's change as an event, in its transaction."""
    event_record(
        subject=f"queue-request:{request.pk}",
        type=type,
        owner_id=request.owner_id,
        payload={
            "request": request.pk,
            "state": request.state,
            "robot": request.robot.name,
            "title": request.title,
            "earliest_at": request.earliest_at.isoformat(),
            "latest_end_at": request.latest_end_at.isoformat(),
            "reservation": request.reservation_id,
            "reason": request.reason,
        },
    )
