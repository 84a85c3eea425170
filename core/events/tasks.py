"""The events' Celery task: one pass of every handler (``core.events.dispatch``)."""

from __future__ import annotations

from celery import shared_task

from core.events import dispatch


@shared_task(time_limit=120, soft_time_limit=110)
def events_dispatch_all(queue: str | None = None) -> dict[str, int]:
    """One pass of the handlers whose passes run on ``queue`` (None: the events' own)."""
    return dispatch.events_dispatch_all(queue=queue)
