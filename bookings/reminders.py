from __future__ import annotations

from datetime import datetime, timedelta

from django.conf import settings
from django.utils import timezone

from bookings.choices import ReservationState
from bookings.models import Reservation


def reservations_due_for_reminder(*, now: datetime) -> list[int]:
    lead = timedelta(seconds=settings.RESERVATION_REMINDER_LEAD_S)
    return list(
        Reservation.objects.filter(
            state=ReservationState.CONFIRMED,
            reminder_sent_at__isnull=True,
            start_at__gt=now,
            start_at__lte=now + lead,
        ).values_list("pk", flat=True)
    )


def reminder_claim(*, reservation_id: int) -> bool:
    """Mark the reminder sent; True for the one caller that claimed it (compare-and-set)."""
    return bool(
        Reservation.objects.filter(pk=reservation_id, reminder_sent_at__isnull=True).update(
            reminder_sent_at=timezone.now()
        )
    )
