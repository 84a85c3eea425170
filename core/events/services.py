"""Writing events and numbering them (see the package's docstring)."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from datetime import datetime
from typing import Any

from django.db import connection, transaction
from django.db.models import Max
from django.utils import timezone

from core import sql
from core.events.catalogue import EVENT_TYPES
from core.events.models import Event

logger = logging.getLogger(__name__)

SEQUENCER_LOCK_KEY = sql.advisory_key(b"eventseq")
# Rows numbered per pass: a backlog (after a crash) is worked through in passes this size.
SEQUENCE_BATCH = 500


def event_record(
    *,
    subject: str,
    type: str,
    payload: Mapping[str, Any],
    owner_id: int | None,
    occurred_at: datetime | None = None,
) -> Event:
    """Write an event in the caller's transaction: it exists if and only if the change does.

    Numbered after the commit (``events_sequence``, run then and by every reader)."""
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
    transaction.on_commit(_sequence_quietly)
    return event


def _sequence_quietly() -> None:
    # After the change committed: number it and wake the handlers (core.events.dispatch). A
    # failure here loses nothing (the next reader or beat's pass does both), so it is logged,
    # never raised into the request that made the change.
    from core.events.tasks import events_dispatch_all

    try:
        if events_sequence():
            events_dispatch_all.delay()
    except Exception:
        logger.exception("numbering events failed; the next reader numbers them")


def events_sequence() -> int:
    """Number every committed event not numbered yet, in the order they were written; how
    many were numbered.

    One sequencer at a time (an advisory lock): each pass sees the rows committed before it
    took the lock and numbers them after every number given before, so a number is never
    given to a row a reader could have skipped. Rows of one subject are written under that
    subject's row lock (the reservation's, the run's), one transaction after the other, so
    their ids, and with them their ``seq``, follow the order of the changes.
    """
    numbered = 0
    while True:
        with transaction.atomic():
            sql.advisory_xact_lock(SEQUENCER_LOCK_KEY)
            pending = list(
                Event.objects.filter(position__isnull=True)
                .order_by("id")
                .only("id", "subject")[:SEQUENCE_BATCH]
            )
            if not pending:
                return numbered
            top = Event.objects.aggregate(top=Max("position"))["top"] or 0
            subjects = {e.subject for e in pending}
            seqs: dict[str, int] = dict(
                Event.objects.filter(subject__in=subjects, seq__isnull=False)
                .values("subject")
                .annotate(top=Max("seq"))
                .values_list("subject", "top")
            )
            for event in pending:
                top += 1
                seqs[event.subject] = seqs.get(event.subject, 0) + 1
                event.position = top
                event.seq = seqs[event.subject]
            Event.objects.bulk_update(pending, ["position", "seq"])
            numbered += len(pending)
        if len(pending) < SEQUENCE_BATCH:
            return numbered
