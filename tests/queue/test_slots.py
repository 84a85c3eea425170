"""Where a queued request fits (``portal/queue/slots.py``): plain functions, checked against a
minute-by-minute reading of the same question, and on Lisbon's two clock changes of 2027."""

from __future__ import annotations

import itertools
from datetime import UTC, datetime, timedelta
from zoneinfo import ZoneInfo

from hypothesis import given, settings
from hypothesis import strategies as st

from portal.queue.slots import allowed_periods, first_fit, intersection, merged, without

LISBON = ZoneInfo("Europe/Lisbon")
T0 = datetime(2027, 1, 4, tzinfo=UTC)


def _at(minute: int) -> datetime:
    return T0 + timedelta(minutes=minute)


periods = st.lists(
    st.tuples(st.integers(0, 600), st.integers(1, 120)).map(
        lambda p: (_at(p[0]), _at(p[0] + p[1]))
    ),
    max_size=6,
)


def _minutes(ps) -> set[int]:
    return {
        m
        for lo, hi in ps
        for m in range(int((lo - T0).total_seconds() // 60), int((hi - T0).total_seconds() // 60))
    }


@settings(max_examples=200, deadline=None)
@given(periods, periods)
def test_intersection_and_without_are_the_minutes_they_say(a, b):
    a, b = merged(a), merged(b)
    assert _minutes(intersection(a, b)) == _minutes(a) & _minutes(b)
    assert _minutes(without(a, b)) == _minutes(a) - _minutes(b)
    # In order and disjoint, as the functions after them expect.
    for ps in (intersection(a, b), without(a, b)):
        assert all(p[1] <= q[0] for p, q in itertools.pairwise(ps))


@settings(max_examples=200, deadline=None)
@given(periods, st.integers(1, 90))
def test_the_first_fit_is_the_first_minute_where_the_length_is_free(free, length_min):
    free = merged(free)
    got = first_fit(free, timedelta(minutes=length_min))
    minutes = _minutes(free)
    starts = [m for m in sorted(minutes) if all(m + k in minutes for k in range(length_min))]
    # A run of free minutes from m means a period holding [m, m + length) (merged touches).
    if not starts:
        assert got is None
    else:
        assert got == (_at(starts[0]), _at(starts[0] + length_min))


def test_nights_only_across_the_autumn_change_have_an_hour_more():
    nights = allowed_periods(
        datetime(2027, 10, 30, 12, tzinfo=UTC),
        datetime(2027, 11, 1, 12, tzinfo=UTC),
        hours_from=22,
        hours_to=6,
        zone=LISBON,
    )
    # 22:00 WEST (21:00 UTC) to 06:00 WET (06:00 UTC): nine hours that night; eight the next.
    assert nights == [
        (datetime(2027, 10, 30, 21, tzinfo=UTC), datetime(2027, 10, 31, 6, tzinfo=UTC)),
        (datetime(2027, 10, 31, 22, tzinfo=UTC), datetime(2027, 11, 1, 6, tzinfo=UTC)),
    ]


def test_hours_the_spring_change_skips_are_not_offered():
    early = allowed_periods(
        datetime(2027, 3, 27, 12, tzinfo=UTC),
        datetime(2027, 3, 29, 12, tzinfo=UTC),
        hours_from=1,
        hours_to=3,
        zone=LISBON,
    )
    # On the 28th, 01:00-02:00 does not exist: 02:00-03:00 WEST is one hour (01-02 UTC).
    assert early == [
        (datetime(2027, 3, 28, 1, tzinfo=UTC), datetime(2027, 3, 28, 2, tzinfo=UTC)),
        (datetime(2027, 3, 29, 0, tzinfo=UTC), datetime(2027, 3, 29, 2, tzinfo=UTC)),
    ]


def test_no_hours_given_is_the_whole_period_and_an_empty_period_is_nothing():
    lo, hi = _at(0), _at(60)
    assert allowed_periods(lo, hi, hours_from=None, hours_to=None, zone=LISBON) == [(lo, hi)]
    assert allowed_periods(hi, lo, hours_from=None, hours_to=None, zone=LISBON) == []
