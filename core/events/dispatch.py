"""Reactions to events: handlers, each handed every event of its types once committed, in order.

A handler is a function of one :class:`~core.events.models.Event`, registered under a name
with the types it wants (``@handler("run-owner-mail", types=[...])``), from the app that owns
the reaction (its ``handlers`` module, imported when the app is ready). ``events_dispatch``
hands it the events after its cursor one at a time, each in a transaction that also moves the
cursor on: a handler that raises leaves its cursor where it was and is handed the same event
again at the next pass, so each event reaches each handler at least once, and in order. Its
side effect must bear a repeat (an e-mail sent twice after a crash between sending and
committing, never zero times).

Passes run in the mail worker (``core.events.tasks.events_dispatch_all``), or in the worker of
the handler's own ``queue`` (the live pushes: the runs worker, so they never wait behind an
e-mail): woken after every commit that wrote events a handler wants, and by beat every minute
besides. Two passes of one handler never overlap: the second finds the cursor's row locked
and leaves.
"""

from __future__ import annotations

import logging
from datetime import timedelta

from django.db import transaction
from django.db.models import Max
from django.utils import timezone

from core.events import registry
from core.events.models import Event, EventCursor
from core.events.registry import handled, handler, handlers
from core.events.sequence import events_sequence

__all__ = ["events_dispatch", "events_dispatch_all", "handled", "handler", "handlers"]

logger = logging.getLogger(__name__)

# Events one pass hands a handler at most: a backlog is worked through pass after pass.
PASS_MAX = 200
# A handler that starts from the end (``from_end``) is still handed the events this recent.
FROM_END_RECENT_S = 300


def events_dispatch(*, name: str, limit: int = PASS_MAX) -> int:
    """Hand the handler ``name`` the events of its types after its cursor, oldest first;
    how many it handled. Raises what the handler raises (its cursor stays before that event).
    """
    registration = registry.registration(name)
    events_sequence()
    if registration.from_end and not EventCursor.objects.filter(handler=name).exists():
        # Past what is older than a moment: the event that woke this first pass still counts.
        old = timezone.now() - timedelta(seconds=FROM_END_RECENT_S)
        top = Event.objects.filter(occurred_at__lt=old).aggregate(top=Max("position"))["top"]
        EventCursor.objects.get_or_create(handler=name, defaults={"position": top or 0})
    else:
        EventCursor.objects.get_or_create(handler=name)
    if registration.active is not None:
        # Read the end first, then ask: what was numbered before a "no" is no one's to handle
        # (a webhook made after it takes the events from then on).
        top = Event.objects.aggregate(top=Max("position"))["top"] or 0
        if not registration.active():
            EventCursor.objects.filter(handler=name, position__lt=top).update(position=top)
            return 0
    handled = 0
    while handled < limit:
        with transaction.atomic():
            cursor = (
                EventCursor.objects.select_for_update(skip_locked=True).filter(handler=name).first()
            )
            if cursor is None:
                return handled  # another pass has it
            event = (
                Event.objects.filter(position__gt=cursor.position, type__in=registration.types)
                .order_by("position")
                .first()
            )
            if event is None:
                return handled
            registration.fn(event)
            cursor.position = event.position or cursor.position
            cursor.save(update_fields=["position", "updated_at"])
        handled += 1
    return handled


def events_dispatch_all(*, queue: str | None = None) -> dict[str, int]:
    """One pass of every handler whose passes run on ``queue`` (None: the events' own, the
    mail worker's); a handler that fails is logged and tried again next pass, and the others
    go on."""
    done: dict[str, int] = {}
    for name, registration in sorted(registry.handlers().items()):
        if registration.queue != queue:
            continue
        try:
            done[name] = events_dispatch(name=name)
        except Exception:
            logger.exception("event handler %s failed; it is handed the same event again", name)
            done[name] = 0
    return done
