"""The events' Celery task: one pass of every handler (``core.events.dispatch``)."""

from __future__ import annotations

from celery import shared_task

from core.events import dispatch
from core.pending import pending_taken


def wake_subject(queue: str | None) -> str:
    """The subject under which one pass of ``queue``'s handlers waits (``core.pending``)."""
    return f"events-dispatch:{queue or ''}"


@shared_task(time_limit=120, soft_time_limit=110)
def events_dispatch_all(queue: str | None = None) -> dict[str, int]:
    """One pass of the handlers whose passes run on ``queue`` (None: the events' own)."""
    pending_taken(wake_subject(queue))
    return dispatch.events_dispatch_all(queue=queue)
