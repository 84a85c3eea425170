"""What the calendar page and the iCalendar feeds show.

Owners (and admins) see their bookings in full; everyone else sees only that a resource is
busy. Maintenance windows are shown to all.
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass
from datetime import UTC, datetime

from django.conf import settings
from django.db.models import Q
from icalendar import Calendar, Event

from bookings.choices import RESERVATION_ACTIVE_STATES, ReservationState
from bookings.models import Blackout, CalendarFeed, Reservation, Resource
from bookings.selectors import external_leases
from core.accounts.models import User


@dataclass(frozen=True)
class Entry:
    uid: str
    kind: str  # "own", "other", "busy", "blackout", "lease"
    title: str
    start_at: datetime
    end_at: datetime
    resources: tuple[str, ...]
    reservation_id: int | None = None
    state: str = ""
    editable: bool = False


def calendar_entries(
    *,
    viewer: User,
    start_at: datetime,
    end_at: datetime,
    resource: Resource | None = None,
    now: datetime,
    only_own: bool = False,
) -> list[Entry]:
    reservations = (
        Reservation.objects.overlapping(start_at, end_at)
        .filter(state__in=(*RESERVATION_ACTIVE_STATES, ReservationState.COMPLETED))
        .select_related("owner")
        .prefetch_related("items__resource")
        .order_by("start_at")
    )
    if resource is not None:
        reservations = reservations.filter(items__resource=resource)
    if only_own:
        reservations = reservations.filter(owner=viewer)
    entries: list[Entry] = []
    for r in reservations.distinct():
        names = tuple(item.resource.name for item in r.items.all())
        mine = r.owner_id == viewer.pk
        if mine or viewer.is_testbed_admin:
            label = r.title or ", ".join(names)
            if not mine:
                label = f"{r.owner.get_username()}: {label}"
            if r.state == ReservationState.REQUESTED:
                label += " (awaiting approval)"
            entries.append(
                Entry(
                    uid=f"reservation-{r.pk}",
                    kind="own" if mine else "other",
                    title=f"{label} [{', '.join(names)}]",
                    start_at=r.start_at,
                    end_at=r.end_at,
                    resources=names,
                    reservation_id=r.pk,
                    state=r.state,
                    editable=mine and r.is_active and r.start_at > now,
                )
            )
        else:
            entries.append(
                Entry(
                    uid=f"busy-{r.pk}",
                    kind="busy",
                    title=f"Busy [{', '.join(names)}]",
                    start_at=r.start_at,
                    end_at=r.end_at,
                    resources=names,
                )
            )
    if not only_own:
        blackouts = Blackout.objects.overlapping(start_at, end_at)
        if resource is not None:
            blackouts = blackouts.filter(Q(all_resources=True) | Q(resources=resource))
        for b in blackouts.prefetch_related("resources").distinct():
            names = ("all",) if b.all_resources else tuple(x.name for x in b.resources.all())
            entries.append(
                Entry(
                    uid=f"blackout-{b.pk}",
                    kind="blackout",
                    title=f"Maintenance: {b.reason} [{', '.join(names)}]",
                    start_at=b.start_at,
                    end_at=b.end_at,
                    resources=names,
                )
            )
        entries += _lease_entries(start_at, end_at, resource)
    return entries


def _lease_entries(start_at: datetime, end_at: datetime, resource: Resource | None) -> list[Entry]:
    entries = []
    for lease in external_leases(start_at, end_at, resource):
        names = tuple(r.name for r in lease.resources.all()) or tuple(lease.components)
        entries.append(
            Entry(
                uid=f"lease-{lease.uuid}",
                kind="lease",
                title=f"Leased on the testbed scheduler: {lease.name} [{', '.join(names)}]",
                start_at=lease.start_at,
                end_at=lease.end_at,
                resources=names,
            )
        )
    return entries


def calendar_feed_for(user: User) -> CalendarFeed:
    feed, _ = CalendarFeed.objects.get_or_create(
        user=user, defaults={"token": secrets.token_urlsafe(32)}
    )
    return feed


def calendar_feed_renew(*, user: User) -> CalendarFeed:
    """A new secret: every URL with the old one stops working at once."""
    feed = calendar_feed_for(user)
    feed.token = secrets.token_urlsafe(32)
    feed.save(update_fields=["token", "created_at"])
    return feed


def ical_document(entries: list[Entry], *, name: str, stamp: datetime) -> bytes:
    cal = Calendar()
    cal.add("prodid", "-//AMazING testbed//mobile-node manager//EN")
    cal.add("version", "2.0")
    cal.add("x-wr-calname", name)
    cal.add("x-wr-timezone", settings.TIME_ZONE)
    for entry in entries:
        event = Event()
        event.add("uid", f"{entry.uid}@amazing-testbed")
        event.add("dtstamp", stamp.astimezone(UTC))
        event.add("dtstart", entry.start_at.astimezone(UTC))
        event.add("dtend", entry.end_at.astimezone(UTC))
        event.add("summary", entry.title)
        if entry.state:
            event.add("status", "TENTATIVE" if entry.state == "requested" else "CONFIRMED")
        cal.add_component(event)
    return cal.to_ical()
