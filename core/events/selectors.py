"""Reading events: a user's own, in order, from a position on."""

from __future__ import annotations

import time

from django.db.models import Q, QuerySet

from core.accounts.models import User
from core.events.models import Event
from core.events.sequence import events_sequence

# A long poll waits at most this long for an event (the web server's threads are few).
WAIT_MAX_S = 20.0
POLL_S = 0.5
LIMIT_MAX = 500


def events_visible(
    *,
    user: User,
    after: int,
    limit: int,
    types: list[str] | None = None,
    subject: str | None = None,
) -> QuerySet[Event]:
    """Numbered events after ``after`` that ``user`` may read, oldest first: their own, and
    for staff (with their second factor) also those of no one (robots, the scheduler); of
    ``types`` and about ``subject`` only, when given."""
    mine = Q(owner=user)
    if user.is_testbed_admin:
        mine |= Q(owner__isnull=True)
    found = Event.objects.filter(mine, position__gt=after)
    if types:
        found = found.filter(type__in=types)
    if subject:
        found = found.filter(subject=subject)
    return found.order_by("position")[:limit]


def events_wait(
    *,
    user: User,
    after: int,
    limit: int,
    wait_s: float,
    types: list[str] | None = None,
    subject: str | None = None,
) -> list[Event]:
    """``events_visible``, waiting up to ``wait_s`` for the first one (a long poll).

    Each look numbers what has committed first (``events_sequence``), so a row whose writer
    died before numbering it is not left behind."""
    deadline = time.monotonic() + min(max(wait_s, 0.0), WAIT_MAX_S)
    while True:
        events_sequence()
        found = list(
            events_visible(user=user, after=after, limit=limit, types=types, subject=subject)
        )
        if found or time.monotonic() >= deadline:
            return found
        time.sleep(POLL_S)


def events_of(*, subject: str, type: str) -> QuerySet[Event]:
    """The events of one type about one subject, numbered or not (those of the caller's
    transaction too)."""
    return Event.objects.filter(subject=subject, type=type)
