"""Local times read as instants (``core.wall_clock``): the hour Lisbon's clocks pass twice is
its first occurrence, the hour they skip is refused with the jump named. The 2027 changes
are at 01:00 UTC on 28 March (01:00 WET becomes 02:00 WEST) and on 31 October (02:00 WEST
becomes 01:00 WET)."""

from __future__ import annotations

import functools
import itertools
from datetime import UTC, datetime, timedelta
from zoneinfo import ZoneInfo

import pytest
from hypothesis import given
from hypothesis import strategies as st

from core.wall_clock import NonexistentLocalTime, local_instant, wall_with_offset

LISBON = ZoneInfo("Europe/Lisbon")


@pytest.mark.parametrize(
    ("wall", "utc"),
    [
        # The repeated hour: its first occurrence, still summer time (UTC+1).
        (datetime(2027, 10, 31, 1, 0), datetime(2027, 10, 31, 0, 0, tzinfo=UTC)),
        (datetime(2027, 10, 31, 1, 30), datetime(2027, 10, 31, 0, 30, tzinfo=UTC)),
        (datetime(2027, 10, 31, 1, 59, 59), datetime(2027, 10, 31, 0, 59, 59, tzinfo=UTC)),
        # Either side of it, one instant each.
        (datetime(2027, 10, 31, 0, 59), datetime(2027, 10, 30, 23, 59, tzinfo=UTC)),
        (datetime(2027, 10, 31, 2, 0), datetime(2027, 10, 31, 2, 0, tzinfo=UTC)),
        # Either side of the skipped hour.
        (datetime(2027, 3, 28, 0, 59, 59), datetime(2027, 3, 28, 0, 59, 59, tzinfo=UTC)),
        (datetime(2027, 3, 28, 2, 0), datetime(2027, 3, 28, 1, 0, tzinfo=UTC)),
        # An ordinary summer and winter day.
        (datetime(2027, 7, 1, 12, 0), datetime(2027, 7, 1, 11, 0, tzinfo=UTC)),
        (datetime(2027, 1, 15, 12, 0), datetime(2027, 1, 15, 12, 0, tzinfo=UTC)),
    ],
)
def test_a_local_time_is_one_instant_the_first_when_it_happens_twice(wall, utc):
    assert local_instant(wall, LISBON) == utc


@pytest.mark.parametrize(
    ("wall", "message"),
    [
        (
            datetime(2027, 3, 28, 1, 30),
            "01:30 does not exist on 28 March 2027 in Europe/Lisbon: "
            "clocks go forward from 01:00 to 02:00",
        ),
        (
            datetime(2027, 3, 28, 1, 0),
            "01:00 does not exist on 28 March 2027 in Europe/Lisbon: "
            "clocks go forward from 01:00 to 02:00",
        ),
        (
            datetime(2027, 3, 28, 1, 59, 59),
            "01:59:59 does not exist on 28 March 2027 in Europe/Lisbon: "
            "clocks go forward from 01:00 to 02:00",
        ),
        (
            # Another zone, another hour: New York skips 02:00-02:59 on 14 March 2027.
            datetime(2027, 3, 14, 2, 15),
            "02:15 does not exist on 14 March 2027 in America/New_York: "
            "clocks go forward from 02:00 to 03:00",
        ),
    ],
)
def test_a_skipped_local_time_is_refused_naming_the_jump(wall, message):
    zone = LISBON if wall.month == 3 and wall.day == 28 else ZoneInfo("America/New_York")
    with pytest.raises(NonexistentLocalTime) as refused:
        local_instant(wall, zone)
    assert str(refused.value) == message


def test_a_time_with_its_own_zone_is_not_a_wall_clock_time():
    with pytest.raises(ValueError, match="no time zone of its own"):
        local_instant(datetime(2027, 10, 31, 1, 30, tzinfo=UTC), LISBON)


def test_the_offset_shown_tells_the_two_occurrences_apart():
    first = datetime(2027, 10, 31, 0, 30, tzinfo=UTC)
    assert wall_with_offset(first, LISBON) == "2027-10-31 01:30 (UTC+01:00)"
    assert wall_with_offset(first + timedelta(hours=1), LISBON) == "2027-10-31 01:30 (UTC+00:00)"


ZONES = ["Europe/Lisbon", "America/New_York", "Australia/Lord_Howe", "Asia/Kolkata", "UTC"]


@functools.cache
def _changes(key: str, year: int) -> list[datetime]:
    """The instants (UTC, to the hour) the zone's offset changes in the year."""
    zone = ZoneInfo(key)
    hours = [datetime(year, 1, 1, tzinfo=UTC) + timedelta(hours=h) for h in range(366 * 24)]
    return [
        b
        for a, b in itertools.pairwise(hours)
        if a.astimezone(zone).utcoffset() != b.astimezone(zone).utcoffset()
    ]


@st.composite
def zoned_walls(draw: st.DrawFn) -> tuple[datetime, str]:
    """A wall-clock time and its zone: half of them within three hours of a clock change."""
    key = draw(st.sampled_from(ZONES))
    changes = _changes(key, draw(st.integers(2024, 2031)))
    near_a_change: bool = draw(st.booleans())
    if changes and near_a_change:
        change = draw(st.sampled_from(changes)).astimezone(ZoneInfo(key)).replace(tzinfo=None)
        near = draw(st.timedeltas(-timedelta(hours=3), timedelta(hours=3)))
        return change + near, key
    return draw(st.datetimes(datetime(2000, 1, 1), datetime(2040, 12, 31))), key


@given(zoned_walls())
def test_every_wall_time_is_its_first_instant_or_refused(zoned):
    """Whatever the time: an accepted one reads back as itself and no earlier instant shows
    it; a refused one shows on no instant at all."""
    wall, key = zoned
    zone = ZoneInfo(key)
    # Every instant the clocks show as ``wall``: one per offset the zone has around then.
    offsets = {
        (wall.replace(tzinfo=UTC) + timedelta(hours=h)).astimezone(zone).utcoffset()
        for h in range(-30, 31)
    }
    showing = sorted(
        instant
        for offset in offsets
        if offset is not None
        and (instant := (wall - offset).replace(tzinfo=UTC)).astimezone(zone).replace(tzinfo=None)
        == wall
    )
    if not showing:
        with pytest.raises(NonexistentLocalTime) as refused:
            local_instant(wall, zone)
        assert refused.value.jump_from <= wall < refused.value.jump_to
    else:
        instant = local_instant(wall, zone)
        assert instant.astimezone(zone).replace(tzinfo=None) == wall
        assert instant == showing[0]
