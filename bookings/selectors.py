from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime, timedelta
from typing import Any

from django.db.models import Prefetch, Q, QuerySet

from bookings.choices import ResourceKind
from bookings.models import (
    CALENDAR_SETUP,
    Blackout,
    PeriodQuerySet,
    Reservation,
    ReservationItem,
    Resource,
    SchedulerLease,
)
from bookings.periods import gaps
from core.accounts.models import User


def resources_by_name() -> dict[str, Resource]:
    """Every resource by its name, kept under the calendar's setup generation (any write to a
    resource moves it on, at its commit): the live check names its resources on every change
    of the booking form. Each call gets its own copies."""
    return CALENDAR_SETUP.answer(
        ("resources-by-name",), lambda: {r.name: r for r in Resource.objects.all()}
    )


def resources_bookable() -> QuerySet[Resource]:
    return Resource.objects.filter(enabled=True)


def mobiles_bookable() -> list[Resource]:
    """The mobile nodes a user may book, by name: every one an admin has not taken out of
    service (a health-check hold is temporary and counts). A program is checked against each
    when written; booking checks it again against the one booked."""
    return list(Resource.objects.filter(kind=ResourceKind.MOBILE, enabled=True).order_by("name"))


def items_overlapping(
    *,
    resources: Iterable[Resource],
    start_at: datetime,
    end_at: datetime,
    exclude_reservation_id: int | None = None,
) -> QuerySet[ReservationItem]:
    """Active holdings of any of ``resources`` that share an instant with ``[start_at, end_at)``."""
    qs = (
        ReservationItem.objects.overlapping(start_at, end_at)
        .filter(resource__in=list(resources), active=True)
        .select_related("resource", "reservation")
    )
    if exclude_reservation_id is not None:
        qs = qs.exclude(reservation_id=exclude_reservation_id)
    return qs


def blackouts_overlapping(
    *, resources: Iterable[Resource], start_at: datetime, end_at: datetime
) -> QuerySet[Blackout]:
    return (
        Blackout.objects.overlapping(start_at, end_at)
        .filter(Q(all_resources=True) | Q(resources__in=list(resources)))
        .distinct()
    )


def reservations_visible(*, user: User) -> PeriodQuerySet[Reservation]:
    # The items with their resources in one query (``items__resource`` would take two).
    qs = Reservation.objects.select_related("owner").prefetch_related(
        Prefetch("items", ReservationItem.objects.select_related("resource"))
    )
    return qs if user.is_testbed_admin else qs.filter(owner=user)


def resource_free_intervals(
    *, resource: Resource, start_at: datetime, end_at: datetime
) -> list[tuple[datetime, datetime]]:
    """The parts of ``[start_at, end_at)`` in which ``resource`` could be booked."""
    if not resource.in_service:
        return []
    busy = list(
        items_overlapping(resources=[resource], start_at=start_at, end_at=end_at).values_list(
            "start_at", "end_at"
        )
    )
    busy += [
        (b.start_at, b.end_at)
        for b in blackouts_overlapping(resources=[resource], start_at=start_at, end_at=end_at)
    ]
    busy += [(x.start_at, x.end_at) for x in external_leases(start_at, end_at, resource)]
    return gaps(busy, start_at, end_at)


def resource_first_free(
    *, resource: Resource, earliest: datetime, length: timedelta, horizon: timedelta
) -> tuple[datetime, datetime] | None:
    """The first slot of ``length``, starting on a whole second no sooner than ``earliest``
    and within ``horizon`` of it, in which ``resource`` could be booked; None if there is
    none. Booking still checks it under its locks (someone may take it meanwhile)."""
    for start, end in resource_free_intervals(
        resource=resource, start_at=earliest, end_at=earliest + horizon
    ):
        if start.microsecond:
            start = start.replace(microsecond=0) + timedelta(seconds=1)
        if end - start >= length:
            return start, start + length
    return None


def busy_slots(*, start_at: datetime, end_at: datetime) -> list[dict[str, Any]]:
    """Every active booking and scheduler lease in ``[start_at, end_at)``, as everyone may
    see it: which resources, when, and the booking's state ("leased" for the scheduler's)."""
    items = items_overlapping(
        resources=Resource.objects.all(), start_at=start_at, end_at=end_at
    ).order_by("start_at")
    busy: dict[int, dict[str, Any]] = {}
    for item in items:
        entry = busy.setdefault(
            item.reservation_id,
            {
                "resources": [],
                "start_at": item.start_at,
                "end_at": item.end_at,
                "state": item.reservation.state,
            },
        )
        entry["resources"].append(item.resource.name)
    rows = list(busy.values())
    # Leases made on the testbed scheduler hold their fixed nodes just the same.
    rows += [
        {
            "resources": [r.name for r in lease.resources.all()],
            "start_at": lease.start_at,
            "end_at": lease.end_at,
            "state": "leased",
        }
        for lease in external_leases(start_at, end_at)
    ]
    rows.sort(key=lambda row: row["start_at"])
    return rows


def external_leases(
    start_at: datetime, end_at: datetime, resource: Resource | None = None
) -> list[SchedulerLease]:
    """Leases made on the testbed scheduler (not for portal bookings) that hold nodes now."""
    leases = SchedulerLease.objects.overlapping(start_at, end_at).filter(
        holds=True, gone_at__isnull=True, reservation__isnull=True
    )
    if resource is not None:
        leases = leases.filter(resources=resource)
    return list(leases.prefetch_related("resources").distinct().order_by("start_at"))
