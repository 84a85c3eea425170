"""Usage of the testbed: booked hours per user, group or resource in a period."""

from __future__ import annotations

from collections import defaultdict
from datetime import UTC, datetime

from bookings.choices import RESERVATION_COUNTED_STATES
from bookings.models import ReservationItem
from bookings.periods import overlap_s

GROUPINGS = ("user", "group", "resource")


def usage_hours(*, start_at: datetime, end_at: datetime, by: str) -> list[tuple[str, float, int]]:
    """``(name, hours, reservations)`` per user / group / resource, most hours first.

    Hours are resource-hours clipped to the period: a two-node reservation of one hour is
    two hours of the testbed. A user in several groups counts in each of them.
    """
    if by not in GROUPINGS:
        raise ValueError(f"group usage by one of {GROUPINGS}")
    start_at, end_at = start_at.astimezone(UTC), end_at.astimezone(UTC)
    items = (
        ReservationItem.objects.overlapping(start_at, end_at)
        .filter(reservation__state__in=RESERVATION_COUNTED_STATES)
        .select_related("resource", "reservation__owner")
        .prefetch_related("reservation__owner__groups")
    )
    hours: dict[str, float] = defaultdict(float)
    reservations: dict[str, set[int]] = defaultdict(set)
    for item in items:
        h = overlap_s(item.start_at, item.end_at, start_at, end_at) / 3600.0
        if by == "user":
            keys = [item.reservation.owner.get_username()]
        elif by == "resource":
            keys = [item.resource.name]
        else:
            keys = [g.name for g in item.reservation.owner.groups.all()] or ["(no group)"]
        for key in keys:
            hours[key] += h
            reservations[key].add(item.reservation_id)
    return sorted(
        ((k, round(v, 3), len(reservations[k])) for k, v in hours.items()),
        key=lambda row: (-row[1], row[0]),
    )
