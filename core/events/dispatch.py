"""Reactions to events: handlers, each handed every event of its types once committed, in order.

A handler is a function of one :class:`~core.events.models.Event`, registered under a name
with the types it wants (``@handler("run-owner-mail", types=[...])``), from the app that owns
the reaction (its ``handlers`` module, imported when the app is ready). ``events_dispatch``
hands it the events after its cursor one at a time, each in a transaction that also moves the
cursor on: a handler that raises leaves its cursor where it was and is handed the same event
again at the next pass, so each event reaches each handler at least once, and in order. Its
side effect must bear a repeat (an e-mail sent twice after a crash between sending and
committing, never zero times).

Passes run in the mail worker (``core.events.tasks.events_dispatch_all``): kicked after every
commit that wrote events, and by beat every ``RUN_SWEEP_INTERVAL_S`` besides. Two passes of
one handler never overlap: the second finds the cursor's row locked and leaves.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from django.db import transaction

from core.events.catalogue import EVENT_TYPES
from core.events.models import Event, EventCursor
from core.events.services import events_sequence

logger = logging.getLogger(__name__)

Handler = Callable[[Event], None]
# Events one pass hands a handler at most: a backlog is worked through pass after pass.
PASS_MAX = 200


@dataclass(frozen=True)
class Registration:
    name: str
    types: frozenset[str]
    fn: Handler


_HANDLERS: dict[str, Registration] = {}


def handler(name: str, *, types: Iterable[str]) -> Callable[[Handler], Handler]:
    """Register ``fn`` as the handler ``name`` of ``types`` (each in the catalogue)."""
    wanted = frozenset(types)
    unknown = sorted(wanted - set(EVENT_TYPES))
    if unknown or not wanted:
        raise ValueError(f"handler {name}: not event types: {unknown or 'none given'}")

    def register(fn: Handler) -> Handler:
        _HANDLERS[name] = Registration(name, wanted, fn)
        return fn

    return register


def handlers() -> dict[str, Registration]:
    return dict(_HANDLERS)


def events_dispatch(*, name: str, limit: int = PASS_MAX) -> int:
    """Hand the handler ``name`` the events of its types after its cursor, oldest first;
    how many it handled. Raises what the handler raises (its cursor stays before that event).
    """
    registration = _HANDLERS[name]
    events_sequence()
    EventCursor.objects.get_or_create(handler=name)
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


def events_dispatch_all() -> dict[str, int]:
    """One pass of every handler; a handler that fails is logged and tried again next pass,
    and the others go on."""
    done: dict[str, int] = {}
    for name in sorted(_HANDLERS):
        try:
            done[name] = events_dispatch(name=name)
        except Exception:
            logger.exception("event handler %s failed; it is handed the same event again", name)
            done[name] = 0
    return done
