"""What the calendar page and the iCalendar feeds show.

Owners (and admins) see their bookings in full; everyone else sees only that a resource is
busy. Maintenance windows are shown to all.
"""

from __future__ import annotations

import hashlib
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


def feed_token_digest(token: str) -> str:
    """What is kept of a feed's secret. Plain SHA-256: the secret is 256 random bits, so
    nothing is gained by a slow or salted hash, and a lookup stays one indexed query."""
    return hashlib.sha256(token.encode()).hexdigest()


def calendar_feed_of(user: User) -> CalendarFeed | None:
    return CalendarFeed.objects.filter(user=user).first()


def calendar_feed_renew(*, user: User) -> str:
    """A new secret, returned once (only its digest is kept): every URL with the old one
    stops working at once."""
    token = secrets.token_urlsafe(32)
    CalendarFeed.objects.update_or_create(
        user=user, defaults={"token_digest": feed_token_digest(token)}
    )
    return token


def calendar_feed_user(token: str) -> User | None:
    """The active user whose feed ``token`` opens, if any."""
    feed = (
        CalendarFeed.objects.filter(token_digest=feed_token_digest(token))
        .select_related("user")
        .first()
    )
    if feed is None or not feed.user.is_active:
        return None
    return feed.user


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
