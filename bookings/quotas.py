"""Quota policies: which apply to a booking, how much of each is used, what is left.

Periods are calendar days, weeks (Monday to Sunday) and months in the testbed's time zone,
so "per day" means the local day a researcher sees, 23 or 25 hours long on the days the
clocks change. Hours are real elapsed hours.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from datetime import UTC, date, datetime, time, timedelta
from zoneinfo import ZoneInfo

from django.conf import settings

from bookings import queries
from bookings.choices import (
    RESERVATION_ACTIVE_STATES,
    RESERVATION_COUNTED_STATES,
    QuotaPeriod,
)
from bookings.models import (
    QUOTA_POLICIES,
    QuotaPolicy,
    Resource,
)
from bookings.periods import overlap_s, overlaps, within
from core.accounts.models import User


def testbed_zone() -> ZoneInfo:
    return ZoneInfo(settings.TIME_ZONE)


def period_bounds(period: str, at: datetime) -> tuple[datetime, datetime]:
    """The local calendar ``period`` that contains the instant ``at``, in UTC.

    UTC because Python subtracts two datetimes of the same zone by wall clock: across a
    clock change that is an hour off. Every instant compared or subtracted here is UTC.
    """
    zone = testbed_zone()
    day = at.astimezone(zone).date()
    if period == QuotaPeriod.DAY:
        first, last = day, day + timedelta(days=1)
    elif period == QuotaPeriod.WEEK:
        first = day - timedelta(days=day.weekday())
        last = first + timedelta(days=7)
    elif period == QuotaPeriod.MONTH:
        first = day.replace(day=1)
        last = (first + timedelta(days=32)).replace(day=1)
    else:
        raise ValueError(f"unknown quota period {period!r}")
    return _local_midnight(first, zone), _local_midnight(last, zone)


def _local_midnight(day: date, zone: ZoneInfo) -> datetime:
    return datetime.combine(day, time(0), tzinfo=zone).astimezone(UTC)


def periods_touched(
    period: str, start_at: datetime, end_at: datetime
) -> Iterator[tuple[datetime, datetime]]:
    """Every period that shares time with ``[start_at, end_at)``."""
    bounds = period_bounds(period, start_at)
    while overlaps(*bounds, start_at, end_at):
        yield bounds
        bounds = period_bounds(period, bounds[1])


def policies_for(
    *, user: User, resources: Iterable[Resource], related: bool = False
) -> list[QuotaPolicy]:
    """The active policies whose scope covers ``user`` booking any of ``resources``.

    Policies are few (an admin writes each one), so they are read in one plain query (kept in
    the cache until one is written) and matched here; the user's groups and the resources'
    groups are read only when some policy is scoped by them. This runs under the booking lock
    on every booking. ``related`` also loads what the scope labels name.
    """
    qs = QuotaPolicy.objects.filter(active=True)
    if related:
        qs = qs.select_related("resource", "resource_group", "group")
    policies = QUOTA_POLICIES.answer(("active", related), lambda: list(qs))
    resource_ids = {r.pk for r in resources}
    group_ids: set[int] = set()
    if any(p.group_id is not None for p in policies):
        group_ids = set(user.groups.values_list("pk", flat=True))
    resource_group_ids: set[int] = set()
    if any(p.resource_group_id is not None for p in policies):
        resource_group_ids = set(
            Resource.groups.through.objects.filter(resource_id__in=resource_ids).values_list(
                "resourcegroup_id", flat=True
            )
        )
    return [
        p
        for p in policies
        if (p.user_id is None or p.user_id == user.pk)
        and (p.group_id is None or p.group_id in group_ids)
        and (p.resource_id is None or p.resource_id in resource_ids)
        and (p.resource_group_id is None or p.resource_group_id in resource_group_ids)
    ]


@dataclass(frozen=True)
class PeriodUsage:
    policy: QuotaPolicy
    period_start: datetime
    period_end: datetime
    used_hours: float
    used_count: int

    @property
    def remaining_hours(self) -> float | None:
        if self.policy.max_hours is None:
            return None
        return max(0.0, self.policy.max_hours - self.used_hours)

    @property
    def remaining_count(self) -> int | None:
        if self.policy.max_count is None:
            return None
        return max(0, self.policy.max_count - self.used_count)


def period_usage(
    policy: QuotaPolicy,
    user: User,
    period_start: datetime,
    period_end: datetime,
    *,
    exclude_id: int | None = None,
) -> PeriodUsage:
    periods = queries.quota_periods(
        policy, user, RESERVATION_COUNTED_STATES, period_start, period_end, exclude_id=exclude_id
    )
    used_s = 0.0
    count = 0
    for start_at, end_at in periods:
        used_s += overlap_s(start_at, end_at, period_start, period_end)
        if within(start_at, period_start, period_end):
            count += 1
    return PeriodUsage(policy, period_start, period_end, used_s / 3600.0, count)


def _upcoming(policy: QuotaPolicy, user: User, *, now: datetime, exclude_id: int | None) -> int:
    """How many of the user's bookings in ``policy``'s scope are still to come (or running)."""
    states = [s for s in RESERVATION_COUNTED_STATES if s in RESERVATION_ACTIVE_STATES]
    return queries.quota_upcoming(policy, user, states, now=now, exclude_id=exclude_id)


def quota_violations(
    *,
    user: User,
    resources: Iterable[Resource],
    start_at: datetime,
    end_at: datetime,
    now: datetime,
    exclude_id: int | None = None,
) -> list[str]:
    """Why this booking would break a quota policy; empty when it fits every one."""
    problems: list[str] = []
    start_at, end_at, now = start_at.astimezone(UTC), end_at.astimezone(UTC), now.astimezone(UTC)
    length_s = (end_at - start_at).total_seconds()
    zone = testbed_zone()
    for policy in policies_for(user=user, resources=resources):
        name = f"“{policy.name}”"
        if policy.max_length_s is not None and length_s > policy.max_length_s:
            problems.append(f"{name} allows reservations of at most {_hours(policy.max_length_s)}.")
        notice_s = (start_at - now).total_seconds()
        if policy.min_notice_s is not None and notice_s < policy.min_notice_s:
            problems.append(f"{name} needs booking at least {_hours(policy.min_notice_s)} ahead.")
        if policy.max_advance_s is not None and notice_s > policy.max_advance_s:
            problems.append(f"{name} allows booking at most {_hours(policy.max_advance_s)} ahead.")
        if policy.max_future is not None:
            upcoming = _upcoming(policy, user, now=now, exclude_id=exclude_id)
            if upcoming + 1 > policy.max_future:
                problems.append(
                    f"{name} allows {policy.max_future} upcoming reservation"
                    f"{'s' if policy.max_future != 1 else ''} at once; you have {upcoming}."
                )
        if not policy.period or (policy.max_hours is None and policy.max_count is None):
            continue
        for period_start, period_end in periods_touched(policy.period, start_at, end_at):
            usage = period_usage(policy, user, period_start, period_end, exclude_id=exclude_id)
            label = _period_label(policy.period, period_start.astimezone(zone))
            needed_h = overlap_s(start_at, end_at, period_start, period_end) / 3600.0
            if (
                policy.max_hours is not None
                and usage.used_hours + needed_h > policy.max_hours + 1e-9
            ):
                problems.append(
                    f"{name} allows {policy.max_hours:g} h per {policy.period}; {label} you have "
                    f"{usage.used_hours:g} h booked and this needs {needed_h:g} h more."
                )
            starts_here = within(start_at, period_start, period_end)
            if (
                policy.max_count is not None
                and starts_here
                and usage.used_count + 1 > policy.max_count
            ):
                problems.append(
                    f"{name} allows {policy.max_count} reservation"
                    f"{'s' if policy.max_count != 1 else ''} per {policy.period}; {label} you have "
                    f"{usage.used_count}."
                )
    return problems


def quota_summary(*, user: User, now: datetime) -> list[dict[str, object]]:
    """Each policy that applies to the user, with its use in the current period."""
    rows: list[dict[str, object]] = []
    resources = Resource.objects.filter(enabled=True)
    for policy in policies_for(user=user, resources=resources, related=True):
        row: dict[str, object] = {
            "policy": policy.name,
            "scope": _scope_label(policy),
            "period": policy.period or None,
            "max_hours": policy.max_hours,
            "max_count": policy.max_count,
            "max_length_s": policy.max_length_s,
            "min_notice_s": policy.min_notice_s,
            "max_advance_s": policy.max_advance_s,
            "max_future": policy.max_future,
        }
        if policy.period:
            start, end = period_bounds(policy.period, now)
            usage = period_usage(policy, user, start, end)
            row.update(
                {
                    "period_start": start,
                    "period_end": end,
                    "used_hours": round(usage.used_hours, 3),
                    "used_count": usage.used_count,
                    "remaining_hours": None
                    if usage.remaining_hours is None
                    else round(usage.remaining_hours, 3),
                    "remaining_count": usage.remaining_count,
                }
            )
        rows.append(row)
    return rows


def _scope_label(policy: QuotaPolicy) -> str:
    parts = []
    if policy.user_id:
        parts.append("you")
    if policy.group_id:
        parts.append(f"group {policy.group}")
    if policy.resource_id:
        parts.append(f"resource {policy.resource}")
    if policy.resource_group_id:
        parts.append(f"resources in {policy.resource_group}")
    return ", ".join(parts) or "everyone, every resource"


def _hours(seconds: float) -> str:
    hours = seconds / 3600.0
    return f"{hours:g} h" if hours >= 1 else f"{seconds / 60:g} min"


def _period_label(period: str, local_start: datetime) -> str:
    if period == QuotaPeriod.DAY:
        return f"on {local_start:%Y-%m-%d}"
    if period == QuotaPeriod.WEEK:
        return f"in the week of {local_start:%Y-%m-%d}"
    return f"in {local_start:%B %Y}"
