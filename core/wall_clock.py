"""Wall-clock times typed in the testbed's zone, read as instants.

Twice a year a local time is not one instant. When clocks go back (Lisbon: the last Sunday of
October, 02:00 summer time becomes 01:00) the hour 01:00-01:59 happens twice; when they go
forward (the last Sunday of March, 01:00 becomes 02:00) the hour 01:00-01:59 never happens.
Every form that takes a local time reads it with :func:`local_instant`: a repeated time is its
first occurrence (the earlier instant, still summer time), a skipped one is refused with a
message that says why. :func:`wall_with_offset` writes an instant back with its UTC offset, so
the researcher sees which occurrence was booked.

No Django here: plain ``zoneinfo``.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from zoneinfo import ZoneInfo


class NonexistentLocalTime(ValueError):
    """A local time the clocks skip: it names the time, the day and the jump."""

    def __init__(self, wall: datetime, zone: ZoneInfo, jump_from: datetime, jump_to: datetime):
        self.wall = wall
        self.zone = zone
        self.jump_from = jump_from
        self.jump_to = jump_to
        super().__init__(
            f"{_clock(wall)} does not exist on {wall.day} {wall:%B %Y} in {zone.key}: "
            f"clocks go forward from {_clock(jump_from)} to {_clock(jump_to)}"
        )


def local_instant(wall: datetime, zone: ZoneInfo) -> datetime:
    """The instant (in UTC) a naive wall-clock time in ``zone`` names.

    A time that happens twice is its first occurrence; a time that never happens raises
    :class:`NonexistentLocalTime`.
    """
    if wall.tzinfo is not None:
        raise ValueError("a wall-clock time has no time zone of its own")
    if _skipped(wall, zone):
        jump_from, jump_to = _gap_around(wall, zone)
        raise NonexistentLocalTime(wall, zone, jump_from, jump_to)
    # In UTC: an aware time in the repeated hour compares unequal to every other zone's
    # (PEP 495), and adding to it counts wall-clock hours, not elapsed ones.
    return wall.replace(tzinfo=zone, fold=0).astimezone(UTC)


def wall_with_offset(instant: datetime, zone: ZoneInfo) -> str:
    """``2027-10-31 01:30 (UTC+01:00)``: the local time and which offset it is in."""
    local = instant.astimezone(zone)
    offset = local.strftime("%z")
    return f"{_day_clock(local)} (UTC{offset[:3]}:{offset[3:]})"


def _skipped(wall: datetime, zone: ZoneInfo) -> bool:
    # A skipped time does not come back from a round trip through UTC.
    first = wall.replace(tzinfo=zone, fold=0)
    return first.astimezone(UTC).astimezone(zone).replace(tzinfo=None) != wall


def _gap_around(wall: datetime, zone: ZoneInfo) -> tuple[datetime, datetime]:
    """The wall-clock times either side of the jump that skips ``wall``."""
    before = wall.replace(tzinfo=zone, fold=0).utcoffset()
    after = wall.replace(tzinfo=zone, fold=1).utcoffset()
    assert before is not None
    assert after is not None
    # The change happens between these two instants; halve the interval to the second.
    early = (wall - after).replace(tzinfo=UTC)
    late = (wall - before).replace(tzinfo=UTC)
    while late - early > timedelta(seconds=1):
        middle = early + (late - early) / 2
        if middle.astimezone(zone).utcoffset() == before:
            early = middle
        else:
            late = middle
    change = late.replace(microsecond=0)
    return (change + before).replace(tzinfo=None), (change + after).replace(tzinfo=None)


def _clock(wall: datetime) -> str:
    return f"{wall:%H:%M:%S}" if wall.second else f"{wall:%H:%M}"


def _day_clock(wall: datetime) -> str:
    return f"{wall:%Y-%m-%d} {_clock(wall)}"
