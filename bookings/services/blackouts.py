"""Maintenance windows (blackouts): declared by an admin, flagging the bookings they overlap."""

from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime, timedelta
from typing import Final

from django.db import transaction
from django.utils import timezone

from bookings.events import reservation_flagged_record
from bookings.models import Blackout, Reservation, ReservationItem, Resource
from bookings.rules import aware_utc
from core.accounts.models import User
from core.audit.services import audit_record
from core.errors import InvalidInput, NotAllowed

# A window may be declared when it has begun already (maintenance under way), not long after:
# one that ended long ago changes nothing the portal does.
BLACKOUT_MAX_PAST: Final = timedelta(days=7)


def blackout_create(
    *,
    by: User,
    start_at: datetime,
    end_at: datetime,
    reason: str,
    resources: Iterable[Resource] = (),
    all_resources: bool = False,
    ip: str | None = None,
) -> tuple[Blackout, list[Reservation]]:
    """Declare a maintenance window; returns it and the reservations it conflicts with.

    Existing reservations are not cancelled (an admin decides); they are flagged, and their
    owners and the admins are told.
    """
    if not by.is_testbed_admin:
        raise NotAllowed("Only admins declare maintenance windows.")
    resources = list(resources)
    if not resources and not all_resources:
        raise InvalidInput.on_field("resources", "Choose the resources, or all of them.")
    if not reason.strip():
        raise InvalidInput.on_field("reason", "Say what the maintenance is.")
    start_at = aware_utc(start_at, "start_at")
    end_at = aware_utc(end_at, "end_at")
    if end_at <= start_at:
        raise InvalidInput.on_field("end_at", "The end must be after the start.")
    if start_at < timezone.now() - BLACKOUT_MAX_PAST:
        raise InvalidInput.on_field(
            "start_at",
            "A maintenance window starts at most 7 days ago (one long past changes "
            "nothing; note it in the log).",
        )
    with transaction.atomic():
        blackout = Blackout(
            start_at=start_at,
            end_at=end_at,
            reason=reason.strip(),
            all_resources=all_resources,
            created_by=by,
        )
        blackout.full_clean()
        blackout.save()
        blackout.resources.set(resources)
        conflicted = _conflicts_flag(
            blackout, resources, all_resources=all_resources, start_at=start_at, end_at=end_at
        )
        audit_record(
            actor=by,
            action="blackout.create",
            target=blackout,
            ip=ip,
            reason=reason,
            resources="all" if all_resources else [r.name for r in resources],
            conflicts=[r.pk for r in conflicted],
        )
        for r in conflicted:
            reservation_flagged_record(
                r, problem="maintenance", note=r.conflict, blackout_id=blackout.pk
            )
    return blackout, conflicted


def _conflicts_flag(
    blackout: Blackout,
    resources: list[Resource],
    *,
    all_resources: bool,
    start_at: datetime,
    end_at: datetime,
) -> list[Reservation]:
    """Flag the bookings the window overlaps (on its resources, or on any when it covers all),
    saying which maintenance and when; returns them, earliest first."""
    items = ReservationItem.objects.overlapping(start_at, end_at).filter(active=True)
    if not all_resources:
        items = items.filter(resource__in=resources)
    conflicted = list(
        Reservation.objects.filter(pk__in=items.values("reservation_id")).order_by("start_at")
    )
    local = timezone.localtime
    note = (
        f"Overlaps maintenance “{blackout.reason}” "
        f"({local(start_at):%Y-%m-%d %H:%M} – {local(end_at):%Y-%m-%d %H:%M})."
    )
    Reservation.objects.filter(pk__in=[r.pk for r in conflicted]).update(conflict=note)
    for r in conflicted:
        r.conflict = note
    return conflicted
