"""The queue's reactions to events (``core.events.dispatch``): a slot freed or moved may let a
waiting request in at once, not only at beat's next pass. Imported when the app is ready."""

from __future__ import annotations

from core.events.dispatch import handler
from core.events.models import Event
from portal.queue.allocation import queue_allocate
from portal.queue.models import QueueRequest, RequestState


def _anyone_waiting() -> bool:
    return QueueRequest.objects.filter(state=RequestState.WAITING).exists()


@handler(
    "queue-allocate",
    types=["reservation.cancelled", "reservation.moved", "reservation.rejected"],
    active=_anyone_waiting,
    from_end=True,
)
def queue_on_calendar_change(event: Event) -> None:
    queue_allocate()
