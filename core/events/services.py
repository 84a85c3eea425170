"""Writing events, and waking the handlers of those committed (see the package's docstring)."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from datetime import datetime
from typing import Any

from django.db import connection
from django.utils import timezone

from core.commit_batch import CommitBatch
from core.events.catalogue import EVENT_TYPES
from core.events.models import Event
from core.events.registry import queues_wanting
from core.events.tasks import events_dispatch_all, wake_subject
from core.pending import queue_once

logger = logging.getLogger(__name__)


def event_record(
    *,
    subject: str,
    type: str,
    payload: Mapping[str, Any],
    owner_id: int | None,
    occurred_at: datetime | None = None,
) -> Event:
    """Write an event in the caller's transaction: it exists if and only if the change does.

    Numbered after the commit (``events_sequence``: by every reader and every pass of the
    handlers, which are woken after the commit when one wants the type)."""
    kind = EVENT_TYPES.get(type)
    if kind is None:
        raise ValueError(f"{type!r} is not an event type (core/events/catalogue.py)")
    if not connection.in_atomic_block:
        raise RuntimeError("event_record belongs inside the transaction of the change")
    event = Event.objects.create(
        subject=subject,
        type=type,
        version=kind.version,
        payload=dict(payload),
        owner_id=owner_id,
        occurred_at=occurred_at or timezone.now(),
    )
    wakes = _Wakes.joinable()
    inactive = set(wakes.inactive) if wakes is not None else set()
    queues = queues_wanting(
        type, woken=wakes.queues if wakes is not None else (), inactive=inactive
    )
    if queues or (inactive and wakes is None):
        # Begun for what it remembers too: without a handler to wake, each of a booking's
        # events asked the webhooks again whether any webhook existed.
        wakes = wakes or _Wakes.current()
    if wakes is not None:
        wakes.queues |= queues
        wakes.inactive |= inactive
    return event


class _Wakes(CommitBatch):
    """The handlers' queues a transaction wakes at its commit: each once, however many of
    its events they want (a booking records several; one pass hands them all out)."""

    def __init__(self) -> None:
        super().__init__()
        self.queues: set[str | None] = set()
        # Handlers found inactive in this transaction, not asked again (``queues_wanting``).
        self.inactive: set[str] = set()

    def run(self) -> None:
        for queue in sorted(self.queues, key=lambda q: q or ""):
            _wake_handlers(queue)


def _wake_handlers(queue: str | None) -> None:
    # After the change committed, if a handler wants it: wake the handlers' pass
    # (core.events.dispatch), which numbers what has committed before it hands anything out.
    # Numbering here, in the request, cost a booking a third of its time (the bench of
    # bookings); events no handler wants cost nothing at commit at all (readers number what
    # they read). A failure here loses nothing (beat's pass comes within a minute), so it is
    # logged, never raised into the request that made the change.
    # Once per queue while a pass waits (core.pending): a burst of bookings wakes one pass,
    # which hands out all their events, not one pass per booking behind one another.
    try:
        if queue is None:
            queue_once(events_dispatch_all, wake_subject(queue))
        else:
            queue_once(
                events_dispatch_all, wake_subject(queue), kwargs={"queue": queue}, queue=queue
            )
    except Exception:
        logger.exception("waking the event handlers failed; beat's next pass hands them out")
