from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime
from typing import Any

from django.db.models import F, Max, Q, QuerySet, Value

from bookings.choices import ResourceKind
from bookings.models import Blackout, Reservation, ReservationItem, Resource
from portal.accounts.models import User


def resources_bookable() -> QuerySet[Resource]:
    return Resource.objects.filter(enabled=True)


def mobile_max_velocity_mps() -> float | None:
    """The highest velocity any enabled mobile node accepts (None when there is none)."""
    return Resource.objects.filter(kind=ResourceKind.MOBILE, enabled=True).aggregate(
        v=Max("max_velocity_mps")
    )["v"]


def items_overlapping(
    *,
    resources: Iterable[Resource],
    start_at: datetime,
    end_at: datetime,
    exclude_reservation_id: int | None = None,
) -> QuerySet[ReservationItem]:
    """Active holdings of any of ``resources`` that share an instant with ``[start_at, end_at)``."""
    qs = ReservationItem.objects.filter(
        resource__in=list(resources), active=True, start_at__lt=end_at, end_at__gt=start_at
    ).select_related("resource", "reservation")
    if exclude_reservation_id is not None:
        qs = qs.exclude(reservation_id=exclude_reservation_id)
    return qs


def blackouts_overlapping(
    *, resources: Iterable[Resource], start_at: datetime, end_at: datetime
) -> QuerySet[Blackout]:
    return (
        Blackout.objects.filter(start_at__lt=end_at, end_at__gt=start_at)
        .filter(Q(all_resources=True) | Q(resources__in=list(resources)))
        .distinct()
    )


def first_conflict(
    *,
    resources: Iterable[Resource],
    start_at: datetime,
    end_at: datetime,
    exclude_reservation_id: int | None = None,
) -> dict[str, Any] | None:
    """The first thing that forbids booking ``resources`` in ``[start_at, end_at)``.

    ``{"kind": "blackout"|"booked", "label": reason or resource name, "start_at", "end_at"}``,
    maintenance first. One round trip: this runs under the booking lock, on every booking.
    """
    ids = [r.pk for r in resources]
    blackout_ids = Blackout.resources.through.objects.filter(resource_id__in=ids).values(
        "blackout_id"
    )
    blackouts = (
        Blackout.objects.filter(start_at__lt=end_at, end_at__gt=start_at)
        .filter(Q(all_resources=True) | Q(pk__in=blackout_ids))
        .annotate(kind=Value("blackout"), label=F("reason"))
        .values("kind", "label", "start_at", "end_at")
        .order_by()  # SQLite allows no ORDER BY inside a compound statement's parts
    )
    items = ReservationItem.objects.filter(
        resource_id__in=ids, active=True, start_at__lt=end_at, end_at__gt=start_at
    )
    if exclude_reservation_id is not None:
        items = items.exclude(reservation_id=exclude_reservation_id)
    booked = (
        items.annotate(kind=Value("booked"), label=F("resource__name"))
        .values("kind", "label", "start_at", "end_at")
        .order_by()
    )
    # "blackout" sorts before "booked": a maintenance window is the better explanation.
    return blackouts.union(booked, all=True).order_by("kind", "start_at").first()


def reservations_visible(*, user: User) -> QuerySet[Reservation]:
    qs = Reservation.objects.select_related("owner", "run").prefetch_related("items__resource")
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
    if not resource.enabled:
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
