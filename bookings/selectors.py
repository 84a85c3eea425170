from __future__ import annotations

from datetime import datetime

from django.db.models import Max, QuerySet

from bookings.choices import RESERVATION_ACTIVE_STATES, ResourceKind
from bookings.models import Reservation, Resource
from portal.accounts.models import User


def resources_bookable() -> QuerySet[Resource]:
    return Resource.objects.filter(enabled=True)


def mobile_max_velocity_mps() -> float | None:
    """The highest velocity any enabled mobile node accepts (None when there is none)."""
    return Resource.objects.filter(kind=ResourceKind.MOBILE, enabled=True).aggregate(
        v=Max("max_velocity_mps")
    )["v"]


def reservations_overlapping(
    *, resource: Resource, start_at: datetime, end_at: datetime
) -> QuerySet[Reservation]:
    """Active reservations of ``resource`` that share any instant with ``[start_at, end_at)``."""
    return Reservation.objects.filter(
        resource=resource,
        state__in=RESERVATION_ACTIVE_STATES,
        start_at__lt=end_at,
        end_at__gt=start_at,
    )


def reservations_visible(*, user: User) -> QuerySet[Reservation]:
    qs = Reservation.objects.select_related("resource", "owner", "run")
    return qs if user.is_testbed_admin else qs.filter(owner=user)
