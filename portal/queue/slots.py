"""Where a queued request fits: plain functions over periods, without the database.

Periods are half-open ``(start, end)`` pairs of aware datetimes, in order and disjoint where a
function says so.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from datetime import UTC, date, datetime, time, timedelta
from zoneinfo import ZoneInfo

Period = tuple[datetime, datetime]


def _local(day: date, hour: int, zone: ZoneInfo) -> datetime:
    """``hour`` o'clock (0-24) of ``day`` in ``zone``. An hour the clock skips (Lisbon's
    01:00 on the last Sunday of March) is read as the instant the clock jumps to; an hour it
    repeats, as the first of the two."""
    if hour == 24:
        day, hour = day + timedelta(days=1), 0
    # fold=0: a skipped time takes the offset before the jump (the jump's instant), a repeated
    # one its first occurrence.
    return datetime.combine(day, time(hour), tzinfo=zone).astimezone(UTC)


def allowed_periods(
    start: datetime,
    end: datetime,
    *,
    hours_from: int | None,
    hours_to: int | None,
    zone: ZoneInfo,
) -> list[Period]:
    """The parts of ``[start, end)`` inside the allowed hours of each local day (``hours_from``
    to ``hours_to``; a range past midnight, 22 to 6, runs into the next day), in order."""
    if start >= end:
        return []
    if hours_from is None or hours_to is None:
        return [(start, end)]
    periods: list[Period] = []
    day = start.astimezone(zone).date() - timedelta(days=1)
    last = end.astimezone(zone).date()
    while day <= last:
        opens = _local(day, hours_from, zone)
        closes_day = day if hours_to > hours_from else day + timedelta(days=1)
        closes = _local(closes_day, hours_to, zone)
        lo, hi = max(opens, start), min(closes, end)
        if lo < hi:
            periods.append((lo, hi))
        day += timedelta(days=1)
    return merged(periods)


def merged(periods: Iterable[Period]) -> list[Period]:
    """The union of ``periods``, in order, touching ones joined."""
    out: list[Period] = []
    for lo, hi in sorted(periods):
        if out and lo <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


def intersection(a: Sequence[Period], b: Sequence[Period]) -> list[Period]:
    """Where two ordered lists of disjoint periods overlap."""
    out: list[Period] = []
    i = j = 0
    while i < len(a) and j < len(b):
        lo, hi = max(a[i][0], b[j][0]), min(a[i][1], b[j][1])
        if lo < hi:
            out.append((lo, hi))
        if a[i][1] < b[j][1]:
            i += 1
        else:
            j += 1
    return out


def without(free: Sequence[Period], taken: Iterable[Period]) -> list[Period]:
    """``free`` less the ``taken`` periods."""
    out: list[Period] = []
    taken = merged(taken)
    for lo, hi in free:
        cursor = lo
        for t_lo, t_hi in taken:
            if t_hi <= cursor or t_lo >= hi:
                continue
            if t_lo > cursor:
                out.append((cursor, t_lo))
            cursor = max(cursor, t_hi)
        if cursor < hi:
            out.append((cursor, hi))
    return out


def first_fit(free: Sequence[Period], length: timedelta) -> Period | None:
    """The first period of ``length`` inside one of ``free`` (ordered), starting on a whole
    second; None if none is long enough."""
    for lo, hi in free:
        if lo.microsecond:
            lo = lo.replace(microsecond=0) + timedelta(seconds=1)
        if hi - lo >= length:
            return lo, lo + length
    return None
