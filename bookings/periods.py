"""Half-open periods ``[start, end)``: the one Python spelling of "these two overlap".

Every period the product keeps (reservations and their items, maintenance windows, the
testbed scheduler's leases, quota periods, a report's range) includes its start and excludes
its end, so two periods back to back share no instant. PostgreSQL's
``tstzrange(start, end, '[)')`` means the same. The portal's ORM queries spell the condition
once, in ``bookings.models.PeriodQuerySet.overlapping``, its hand-written SQL once, in
``core.sql.overlap`` (the booking check's one round trip, the quotas' reads), and the agent
once, in ``basestation.store.overlap_condition`` (SQLite); ``tests/bookings/test_overlap.py``
holds them all to agree with PostgreSQL, and ``tests/test_architecture.py`` refuses a
start/end comparison anywhere else.

A period is not empty (``start < end``: the models' check constraints and the services'
"the end must be after the start" see to it). ``None`` for a bound of :func:`overlaps` means
unbounded on that side, as a list filter given only one end.

No Django here: the scheduler adapter, which is plain Python, imports it.
"""

from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime


def overlaps(
    a_start: datetime | None,
    a_end: datetime | None,
    b_start: datetime | None,
    b_end: datetime | None,
) -> bool:
    """Whether ``[a_start, a_end)`` and ``[b_start, b_end)`` share an instant.

    They do exactly when each starts before the other ends; back to back is no overlap.
    """
    return _starts_before(a_start, b_end) and _starts_before(b_start, a_end)


def _starts_before(start: datetime | None, end: datetime | None) -> bool:
    return start is None or end is None or start < end


def within(instant: datetime, start: datetime, end: datetime) -> bool:
    """Whether ``instant`` lies in ``[start, end)``: a period holds its start, not its end."""
    return start <= instant < end


def clip(
    start: datetime, end: datetime, window_start: datetime, window_end: datetime
) -> tuple[datetime, datetime] | None:
    """The part of ``[start, end)`` inside ``[window_start, window_end)``; None if no part."""
    if not overlaps(start, end, window_start, window_end):
        return None
    return max(start, window_start), min(end, window_end)


def overlap_s(a_start: datetime, a_end: datetime, b_start: datetime, b_end: datetime) -> float:
    """Seconds that ``[a_start, a_end)`` and ``[b_start, b_end)`` share (0.0 if they do not)."""
    part = clip(a_start, a_end, b_start, b_end)
    return 0.0 if part is None else (part[1] - part[0]).total_seconds()


def gaps(
    busy: Iterable[tuple[datetime, datetime]], window_start: datetime, window_end: datetime
) -> list[tuple[datetime, datetime]]:
    """The parts of ``[window_start, window_end)`` that no period of ``busy`` covers, in order.

    ``busy`` may overlap itself, be unordered and reach outside the window.
    """
    free: list[tuple[datetime, datetime]] = []
    cursor = window_start
    parts = (clip(s, e, window_start, window_end) for s, e in busy)
    for part_start, part_end in sorted(part for part in parts if part is not None):
        if cursor < part_start:
            free.append((cursor, part_start))
        cursor = max(cursor, part_end)
    if cursor < window_end:
        free.append((cursor, window_end))
    return free
