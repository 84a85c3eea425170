"""Quota rules across day, week and month boundaries and Europe/Lisbon's clock changes.

In 2026 Lisbon springs forward on 29 March (01:00 → 02:00, a 23-hour day) and falls back on
25 October (02:00 → 01:00, a 25-hour day).
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from zoneinfo import ZoneInfo

import pytest
from django.contrib.auth.models import Group
from django.db import transaction
from hypothesis import given, settings
from hypothesis import strategies as st

from bookings import queries
from bookings.choices import RESERVATION_COUNTED_STATES, QuotaPeriod
from bookings.models import QuotaPolicy, Reservation, ResourceGroup
from bookings.quotas import period_bounds, policies_for, quota_summary
from bookings.rules import QuotaExceeded
from bookings.services import reservation_cancel, reservation_create
from core.accounts.models import User
from core.audit.models import AuditEvent
from core.errors import NotAllowed
from tests.factories import FixedResourceFactory

pytestmark = pytest.mark.django_db

LISBON = ZoneInfo("Europe/Lisbon")
# Real elapsed hours are added in UTC: Python adds to a zoned datetime by wall clock.
BEFORE = datetime(2026, 1, 1, tzinfo=LISBON)  # "now" for every booking below
MICROSECOND = timedelta(microseconds=1)


def at(*args: int) -> datetime:
    return datetime(*args, tzinfo=LISBON)


def later(start: datetime, hours: float) -> datetime:
    return start.astimezone(UTC) + timedelta(hours=hours)


def book(owner, start, hours, node=None, **kwargs):
    node = node or FixedResourceFactory()
    return reservation_create(
        owner=owner,
        resource=node,
        start_at=start,
        end_at=later(start, hours),
        now=kwargs.pop("now", BEFORE),
        **kwargs,
    )


def policy(**fields) -> QuotaPolicy:
    return QuotaPolicy.objects.create(name=fields.pop("name", "limit"), **fields)


@pytest.mark.parametrize(
    ("day", "hours"),
    [((2026, 3, 29), 23), ((2026, 10, 25), 25), ((2026, 6, 1), 24)],
)
def test_a_day_is_the_local_calendar_day(day, hours):
    start, end = period_bounds(QuotaPeriod.DAY, at(*day, 12))
    assert start == at(*day)
    assert start.tzinfo == UTC
    assert (end - start).total_seconds() == hours * 3600


def test_weeks_start_on_monday_and_months_on_the_first_locally():
    start, end = period_bounds(QuotaPeriod.WEEK, at(2026, 3, 29, 23, 59))  # a Sunday
    assert (start, end) == (at(2026, 3, 23), at(2026, 3, 30))
    assert (end - start).total_seconds() == (7 * 24 - 1) * 3600  # the week that lost an hour
    start, end = period_bounds(QuotaPeriod.MONTH, at(2026, 10, 31, 23, 30))
    assert (start, end) == (at(2026, 10, 1), at(2026, 11, 1))


def test_hours_per_day_count_real_hours_on_the_long_autumn_day(owner):
    policy(user=owner, period=QuotaPeriod.DAY, max_hours=3)
    # 00:00 to 03:00 local on 25 October lasts four real hours: the clock passes 01:00 twice.
    start = at(2026, 10, 25, 0)
    end = datetime(2026, 10, 25, 3, tzinfo=LISBON)
    assert (end.astimezone(UTC) - start.astimezone(UTC)).total_seconds() == 4 * 3600
    node = FixedResourceFactory()
    with pytest.raises(QuotaExceeded, match="allows 3 h per day; on 2026-10-25 you have 0 h"):
        reservation_create(owner=owner, resource=node, start_at=start, end_at=end, now=BEFORE)
    reservation_create(
        owner=owner, resource=node, start_at=start, end_at=later(start, 3), now=BEFORE
    )


def test_a_booking_across_midnight_counts_in_each_day(owner):
    policy(user=owner, period=QuotaPeriod.DAY, max_hours=2)
    book(owner, at(2026, 5, 4, 23), 2)  # 1 h on the 4th, 1 h on the 5th
    book(owner, at(2026, 5, 4, 10), 1)  # the 4th is now full
    with pytest.raises(QuotaExceeded, match="on 2026-05-04 you have 2 h"):
        book(owner, at(2026, 5, 4, 12), 1)
    book(owner, at(2026, 5, 5, 10), 1)  # the 5th had 1 h left
    with pytest.raises(QuotaExceeded, match="on 2026-05-05"):
        book(owner, at(2026, 5, 5, 14), 1)


def test_a_booking_across_the_spring_change_and_a_week_boundary(owner):
    policy(user=owner, period=QuotaPeriod.WEEK, max_hours=3)
    # Sunday 29 March 22:00 → Monday 02:00: 2 h in the week of 23 March, 2 h in the next.
    book(owner, at(2026, 3, 29, 22), 4)
    book(owner, at(2026, 3, 24, 9), 1)
    with pytest.raises(QuotaExceeded, match="in the week of 2026-03-23 you have 3 h"):
        book(owner, at(2026, 3, 25, 9), 1)
    book(owner, at(2026, 4, 1, 9), 1)  # the next week holds 2 + 1


def test_a_month_boundary_and_counts_per_month(owner):
    policy(user=owner, period=QuotaPeriod.MONTH, max_count=2)
    book(owner, at(2026, 10, 31, 23), 2)  # starts in October
    book(owner, at(2026, 10, 5, 9), 1)
    with pytest.raises(QuotaExceeded, match="allows 2 reservations per month; in October 2026"):
        book(owner, at(2026, 10, 6, 9), 1)
    book(owner, at(2026, 11, 2, 9), 1)
    book(owner, at(2026, 11, 3, 9), 1)  # the one crossing into November counted in October


def test_cancelled_bookings_give_their_quota_back(owner):
    policy(user=owner, period=QuotaPeriod.WEEK, max_hours=1)
    first = book(owner, at(2026, 6, 2, 9), 1)
    with pytest.raises(QuotaExceeded):
        book(owner, at(2026, 6, 3, 9), 1)
    reservation_cancel(reservation=first, by=owner)
    book(owner, at(2026, 6, 3, 9), 1)


def test_length_notice_advance_and_upcoming_limits(owner):
    policy(
        user=owner, max_length_s=2 * 3600, min_notice_s=3600, max_advance_s=30 * 86400, max_future=2
    )
    now = at(2026, 6, 1, 12)
    with pytest.raises(QuotaExceeded, match="at most 2 h"):
        book(owner, at(2026, 6, 2, 9), 3, now=now)
    with pytest.raises(QuotaExceeded, match="at least 1 h ahead"):
        book(owner, at(2026, 6, 1, 12, 30), 1, now=now)
    with pytest.raises(QuotaExceeded, match="at most 720 h ahead"):
        book(owner, at(2026, 7, 15, 9), 1, now=now)
    book(owner, at(2026, 6, 2, 9), 1, now=now)
    book(owner, at(2026, 6, 3, 9), 1, now=now)
    with pytest.raises(QuotaExceeded, match="2 upcoming reservations at once; you have 2"):
        book(owner, at(2026, 6, 4, 9), 1, now=now)


def test_policies_apply_only_within_their_scope(owner, other):
    students = Group.objects.create(name="students")
    other.groups.add(students)
    robot = FixedResourceFactory(name="node-24")
    policy(group=students, period=QuotaPeriod.DAY, max_hours=1)
    policy(resource=robot, period=QuotaPeriod.DAY, max_count=1)
    book(owner, at(2026, 6, 2, 9), 3)  # not a student
    with pytest.raises(QuotaExceeded):
        book(other, at(2026, 6, 2, 9), 2)
    book(owner, at(2026, 6, 3, 9), 1, node=robot)
    with pytest.raises(QuotaExceeded, match="1 reservation per day"):
        book(owner, at(2026, 6, 3, 11), 1, node=robot)
    book(owner, at(2026, 6, 3, 11), 1)  # another resource is outside that policy


def test_each_scope_narrows_which_bookings_a_policy_covers(owner, other):
    students = Group.objects.create(name="students")
    owner.groups.add(students)
    outdoor = ResourceGroup.objects.create(name="outdoor")
    roof, lab = FixedResourceFactory(name="node-01"), FixedResourceFactory(name="node-02")
    roof.groups.add(outdoor)
    everyone = policy(name="everyone")
    mine = policy(name="mine", user=owner)
    student = policy(name="students", group=students)
    on_roof = policy(name="roof node", resource=roof)
    outdoors = policy(name="outdoor nodes", resource_group=outdoor)
    both = policy(name="students outdoors", group=students, resource_group=outdoor)
    policy(name="switched off", active=False)

    def names(user, *resources):
        return {p.name for p in policies_for(user=user, resources=resources)}

    assert names(owner, roof) == {
        p.name for p in (everyone, mine, student, on_roof, outdoors, both)
    }
    assert names(owner, lab) == {p.name for p in (everyone, mine, student)}
    assert names(other, roof) == {p.name for p in (everyone, on_roof, outdoors)}
    assert names(other, lab) == {everyone.name}
    # A booking of several resources is covered by a policy on any of them.
    assert names(other, lab, roof) == names(other, roof)


def test_an_admin_override_needs_a_reason_and_is_audited(owner, admin_user):
    policy(user=owner, period=QuotaPeriod.DAY, max_hours=1)
    book(owner, at(2026, 6, 2, 9), 1)
    with pytest.raises(NotAllowed):
        book(owner, at(2026, 6, 2, 11), 1, override_reason="I want it")
    with pytest.raises(QuotaExceeded):
        book(owner, at(2026, 6, 2, 11), 1, by=admin_user)
    reservation = book(owner, at(2026, 6, 2, 11), 1, by=admin_user, override_reason="calibration")
    assert reservation.override_reason == "calibration"
    event = AuditEvent.objects.get(action="reservation.override")
    assert event.actor == admin_user
    assert event.reason == "calibration"
    assert "allows 1 h per day" in event.data["overridden"][0]


def test_the_summary_shows_what_is_left(owner):
    policy(name="Weekly robot time", user=owner, period=QuotaPeriod.WEEK, max_hours=4)
    book(owner, at(2026, 6, 2, 9), 1.5)
    [row] = quota_summary(user=owner, now=at(2026, 6, 1, 8))
    assert row["policy"] == "Weekly robot time"
    assert row["used_hours"] == 1.5
    assert row["remaining_hours"] == 2.5


@settings(max_examples=40, deadline=None)
@given(
    start=st.datetimes(
        min_value=datetime(2000, 1, 1), max_value=datetime(2100, 1, 1), timezones=st.just(UTC)
    )
)
def test_usage_reads_each_instant_as_stored(start: datetime) -> None:
    """The quota's usage reads its rows' instants as text (``core.sql.instant``), to the
    microsecond, whatever the date."""
    with transaction.atomic():
        owner = User.objects.create(username="instants")
        Reservation.objects.create(owner=owner, start_at=start, end_at=start + MICROSECOND)
        policy = QuotaPolicy.objects.create(name="instants", user=owner)
        read = queries.quota_periods(
            policy, owner, RESERVATION_COUNTED_STATES, start - MICROSECOND, start + 2 * MICROSECOND
        )
        assert read == [(start, start + MICROSECOND)]
        transaction.set_rollback(True)
