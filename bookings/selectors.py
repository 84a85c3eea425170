from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime

from django.db.models import Q, QuerySet

from bookings.choices import ResourceKind
from bookings.models import Blackout, Reservation, ReservationItem, Resource, SchedulerLease
from portal.accounts.models import User


def resources_bookable() -> QuerySet[Resource]:
    return Resource.objects.filter(enabled=True)


def fastest_mobile() -> Resource | None:
    """The enabled mobile node with the highest velocity limit (None when there is none).

    A program is checked against it when written, before it is booked on a particular node.
    """
    return (
        Resource.objects.filter(kind=ResourceKind.MOBILE, enabled=True)
        .order_by("-max_velocity_mps", "name")
        .first()
    )


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


def reservations_visible(*, user: User) -> QuerySet[Reservation]:
    qs = Reservation.objects.select_related("owner").prefetch_related("items__resource")
    return qs if user.is_testbed_admin else qs.filter(owner=user)


def resource_free_intervals(
    *, resource: Resource, start_at: datetime, end_at: datetime
) -> list[tuple[datetime, datetime]]:
    """The parts of ``[start_at, end_at)`` in which ``resource`` could be booked."""
    busy = [
        (max(s, start_at), min(e, end_at))
        for s, e in items_overlapping(resources=[resource], start_at=start_at, end_at=end_at)
        .order_by("start_at")
        .values_list("start_at", "end_at")
    ]
    busy += [
        (max(b.start_at, start_at), min(b.end_at, end_at))
        for b in blackouts_overlapping(resources=[resource], start_at=start_at, end_at=end_at)
    ]
    busy += [
        (max(lease.start_at, start_at), min(lease.end_at, end_at))
        for lease in external_leases(start_at, end_at, resource)
    ]
    if not resource.in_service:
        busy = [(start_at, end_at)]
    free: list[tuple[datetime, datetime]] = []
    cursor = start_at
    for s, e in sorted(busy):
        if s > cursor:
            free.append((cursor, s))
        cursor = max(cursor, e)
    if cursor < end_at:
        free.append((cursor, end_at))
    return free


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
