from __future__ import annotations

import uuid
from collections.abc import Callable, Iterable, Mapping, Sequence
from datetime import UTC, datetime, timedelta
from typing import Any, TypeVar
from urllib.parse import urlsplit

from django.conf import settings
from django.contrib.auth.models import Group
from django.core.exceptions import ValidationError
from django.db import models

from bookings.choices import BookedVia, QuotaPeriod, ReservationState, ResourceKind
from core.accounts.models import User
from core.cache import (
    ChangeTrackedQuerySet,
    Generation,
    Scope,
    ScopeTracked,
    track_changes,
    track_saves,
    track_scoped_changes,
)

_Timed = TypeVar("_Timed", bound=models.Model)
HOLD_REASON_MAX_CHARS = 300


class PeriodQuerySet(ChangeTrackedQuerySet[_Timed]):
    """Rows that hold a half-open period ``[start_at, end_at)``."""

    def overlapping(
        self, start_at: datetime | None, end_at: datetime | None
    ) -> PeriodQuerySet[_Timed]:
        """Rows sharing an instant with ``[start_at, end_at)``: back to back is no overlap.

        ``None`` leaves the window open on that side (a list filter given only one end).
        The one place the portal's ORM queries spell this condition, as ``core.sql.overlap``
        spells it for hand-written SQL and ``bookings/periods.py`` ``overlaps`` in Python; the
        PostgreSQL exclusion constraint on reservation items (migration 0002) uses the same
        half-open ``[)`` ranges.
        """
        qs = self
        if end_at is not None:
            qs = qs.filter(start_at__lt=end_at)
        if start_at is not None:
            qs = qs.filter(end_at__gt=start_at)
        return qs


def validate_agent_url(value: str) -> None:
    """``http(s)://host[:port][/path]``, where host may be a bare name such as ``agent``."""
    parts = urlsplit(value)
    try:
        port_ok = parts.port is None or parts.port > 0
    except ValueError:
        port_ok = False
    if parts.scheme not in ("http", "https") or not parts.hostname or not port_ok:
        raise ValidationError(
            "Not an http(s) URL: %(value)s (e.g. http://basestation:8700).",
            code="invalid",
            params={"value": value},
        )


class ResourceGroup(models.Model):
    """Resources that quota policies and the calendar treat together (e.g. "north side")."""

    name = models.SlugField(max_length=64, unique=True)
    description = models.CharField(max_length=200, blank=True)

    objects = ChangeTrackedQuerySet["ResourceGroup"].as_manager()

    class Meta:
        ordering = ["name"]

    def __str__(self) -> str:
        return self.name


class Resource(models.Model):
    """A bookable thing on the rooftop: the mobile node or one of the fixed nodes."""

    name = models.SlugField(max_length=64, unique=True)
    kind = models.CharField(max_length=8, choices=ResourceKind.choices)
    description = models.CharField(max_length=200, blank=True)
    groups = models.ManyToManyField(ResourceGroup, blank=True, related_name="resources")
    # Mobile nodes only: where their base-station agent listens, and which configured
    # token (a name in settings.AGENT_TOKENS, never the secret itself) authenticates to it.
    # Not a URLField: its validator wants a top-level domain, and agents are often reached by
    # a bare host name (a compose service, a name on the testbed's LAN).
    agent_url = models.CharField(max_length=200, blank=True, validators=[validate_agent_url])
    agent_token_name = models.CharField(max_length=64, default="default", blank=True)
    max_velocity_mps = models.FloatField(
        null=True,
        blank=True,
        help_text="m/s; never above what the robot's base station allows (shown below once "
        "its agent has reported it).",
    )
    max_accel_mps2 = models.FloatField(null=True, blank=True)
    # What the robot's agent reports in ``GET /status`` (its effective AGENT_MAX_* limits and
    # the hard maximum compiled into the robot's firmware), recorded by the health sweep.
    # Each layer is only stricter: firmware ≥ agent ≥ this resource's own limits.
    agent_max_velocity_mps = models.FloatField(null=True, blank=True, editable=False)
    agent_max_accel_mps2 = models.FloatField(null=True, blank=True, editable=False)
    robot_hard_max_velocity_mps = models.FloatField(null=True, blank=True, editable=False)
    agent_limits_at = models.DateTimeField(null=True, blank=True, editable=False)
    enabled = models.BooleanField(
        default=True, help_text="Off takes the resource out of service: nothing can be booked."
    )
    requires_approval = models.BooleanField(
        default=False, help_text="Bookings wait for an admin's decision."
    )
    # Set by the robot health check (a latched e-stop, a fault, a low battery, an agent out of
    # reach): out of service like ``enabled`` off, until an admin puts it back in service.
    # A database default too: rows written by the previous release during an upgrade.
    hold_reason = models.CharField(max_length=HOLD_REASON_MAX_CHARS, blank=True, db_default="")
    held_at = models.DateTimeField(null=True, blank=True)
    # Since when the robot's agent has not answered the health check, over a row of failed
    # checks; None while it answers. Here, not in the cache, so that a restarted cache does
    # not start the count again (and an agent out of reach for good is still held).
    agent_unreachable_since = models.DateTimeField(null=True, blank=True, editable=False)

    objects = ChangeTrackedQuerySet["Resource"].as_manager()

    class Meta:
        ordering = ["kind", "name"]
        constraints = [
            models.CheckConstraint(
                condition=~models.Q(kind=ResourceKind.MOBILE)
                | (models.Q(max_velocity_mps__gt=0) & models.Q(max_accel_mps2__gt=0)),
                name="resource_mobile_has_limits",
            ),
        ]

    def __str__(self) -> str:
        return self.name

    @property
    def is_mobile(self) -> bool:
        return self.kind == ResourceKind.MOBILE

    @property
    def agent_is_stricter(self) -> bool:
        """The agent reported a lower velocity limit than this resource's own: programs are
        checked against the agent's, and the resource's limit should be lowered to match."""
        return (
            self.agent_max_velocity_mps is not None
            and self.max_velocity_mps is not None
            and self.agent_max_velocity_mps < self.max_velocity_mps
        )

    @property
    def in_service(self) -> bool:
        """Bookable: neither taken out of service by an admin nor held by the health check."""
        return self.enabled and not self.hold_reason


class AgentCredential(models.Model):
    """The bearer token the portal presents to one robot's agent, encrypted at rest.

    The portal must send the token, so it keeps the token itself, not a hash; a database
    dump or backup alone does not give it away (``bookings/agent_tokens.py`` encrypts it
    with a key derived from ``DJANGO_SECRET_KEY``). The agent keeps only digests. During a
    rotation ``next_token_encrypted`` holds the new token: the portal still presents the
    current one until the rotation is finished, the agent accepts both.
    """

    resource = models.OneToOneField(
        Resource, on_delete=models.CASCADE, related_name="agent_credential"
    )
    token_encrypted = models.TextField()
    next_token_encrypted = models.TextField(blank=True, default="")
    issued_at = models.DateTimeField()
    rotation_started_at = models.DateTimeField(null=True, blank=True)

    def __str__(self) -> str:
        return f"agent token of {self.resource_id}"


class Reservation(ScopeTracked, models.Model):
    """One or more resources held by a user for ``[start_at, end_at)``."""

    owner = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="reservations"
    )
    resources: models.ManyToManyField[Resource, ReservationItem] = models.ManyToManyField(
        Resource, through="ReservationItem", related_name="reservations"
    )
    start_at = models.DateTimeField()
    end_at = models.DateTimeField()
    state = models.CharField(
        max_length=16, choices=ReservationState.choices, default=ReservationState.CONFIRMED
    )
    title = models.CharField(max_length=200, blank=True)
    # Set when an admin booked past a quota rule; the audit log has the same reason.
    override_reason = models.TextField(blank=True)
    decided_by = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="+",
    )
    decided_at = models.DateTimeField(null=True, blank=True)
    decision_reason = models.TextField(blank=True)
    cancelled_by = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="+",
    )
    cancel_reason = models.TextField(blank=True)
    # A maintenance window declared after the booking overlaps it, or a lease on the testbed's
    # scheduler appeared over it, or its own lease vanished there: shown to owner and admins.
    conflict = models.TextField(blank=True)
    # The reservation's own id outside the portal: the lease on the testbed's scheduler that
    # holds its scheduler-owned nodes is named after it (before the reservation is committed),
    # and the inbound lease API answers it as the lease's uuid.
    public_id = models.UUIDField(default=uuid.uuid4, unique=True, editable=False)
    # That lease's uuid on the scheduler; empty when the booking holds no scheduler-owned node.
    lease_uuid = models.CharField(max_length=64, blank=True)
    booked_via = models.CharField(
        max_length=16, choices=BookedVia.choices, default=BookedVia.PORTAL, editable=False
    )
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    objects = PeriodQuerySet["Reservation"].as_manager()

    class Meta:
        ordering = ["start_at"]
        indexes = [
            models.Index(fields=["owner", "start_at"]),
            models.Index(fields=["state", "start_at"]),
        ]
        constraints = [
            models.CheckConstraint(
                condition=models.Q(end_at__gt=models.F("start_at")),
                name="reservation_end_after_start",
            ),
        ]
        permissions = [
            (
                "lease_inbound",
                "May book the mobile nodes for testbed users through the lease API "
                "(the testbed scheduler's service account)",
            ),
        ]

    def __str__(self) -> str:
        names = ", ".join(item.resource.name for item in self.items.all())
        return f"{names} {self.start_at:%Y-%m-%d %H:%M}-{self.end_at:%H:%M}"

    @property
    def is_active(self) -> bool:
        return self.state in (ReservationState.REQUESTED, ReservationState.CONFIRMED)


class ReservationItem(ScopeTracked, models.Model):
    """One resource of a reservation, with the period copied so one index can guard it.

    On PostgreSQL an exclusion constraint (migration 0002) forbids two active items of the
    same resource with overlapping periods; the services check the same under a lock first,
    which is the only guard on SQLite.
    """

    reservation = models.ForeignKey(Reservation, on_delete=models.CASCADE, related_name="items")
    resource = models.ForeignKey(Resource, on_delete=models.PROTECT, related_name="items")
    start_at = models.DateTimeField()
    end_at = models.DateTimeField()
    active = models.BooleanField(default=True)

    objects = PeriodQuerySet["ReservationItem"].as_manager()

    class Meta:
        indexes = [models.Index(fields=["resource", "start_at", "end_at"])]
        constraints = [
            models.UniqueConstraint(
                fields=["reservation", "resource"], name="reservation_item_unique"
            ),
            models.CheckConstraint(
                condition=models.Q(end_at__gt=models.F("start_at")),
                name="reservation_item_end_after_start",
            ),
        ]

    def __str__(self) -> str:
        return f"{self.resource} in {self.reservation_id}"


class Blackout(models.Model):
    """A maintenance window: no new bookings of its resources (or of all) during it."""

    resources = models.ManyToManyField(Resource, blank=True, related_name="blackouts")
    all_resources = models.BooleanField(default=False)
    start_at = models.DateTimeField()
    end_at = models.DateTimeField()
    reason = models.CharField(max_length=200)
    created_by = models.ForeignKey(
        settings.AUTH_USER_MODEL, null=True, on_delete=models.SET_NULL, related_name="+"
    )
    created_at = models.DateTimeField(auto_now_add=True)

    objects = PeriodQuerySet["Blackout"].as_manager()

    class Meta:
        ordering = ["start_at"]
        constraints = [
            models.CheckConstraint(
                condition=models.Q(end_at__gt=models.F("start_at")),
                name="blackout_end_after_start",
            ),
        ]

    def __str__(self) -> str:
        return f"{self.reason} {self.start_at:%Y-%m-%d %H:%M}"


class QuotaPolicy(models.Model):
    """A limit set by admins. Every field left empty means "no limit of this kind".

    Scope: a policy applies to a booking when each scope field it sets matches — the user,
    a group of the user, a resource of the booking, or a resource group of one of them.
    """

    name = models.CharField(max_length=100)
    user = models.ForeignKey(
        settings.AUTH_USER_MODEL, null=True, blank=True, on_delete=models.CASCADE, related_name="+"
    )
    group = models.ForeignKey(Group, null=True, blank=True, on_delete=models.CASCADE)
    resource = models.ForeignKey(Resource, null=True, blank=True, on_delete=models.CASCADE)
    resource_group = models.ForeignKey(
        ResourceGroup, null=True, blank=True, on_delete=models.CASCADE
    )
    period = models.CharField(max_length=8, choices=QuotaPeriod.choices, blank=True)
    max_hours = models.FloatField(null=True, blank=True)
    max_count = models.PositiveIntegerField(null=True, blank=True)
    max_length_s = models.PositiveIntegerField(null=True, blank=True)
    min_notice_s = models.PositiveIntegerField(null=True, blank=True)
    max_advance_s = models.PositiveIntegerField(null=True, blank=True)
    max_future = models.PositiveIntegerField(
        null=True, blank=True, help_text="Most upcoming reservations held at once."
    )
    active = models.BooleanField(default=True)
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    objects = ChangeTrackedQuerySet["QuotaPolicy"].as_manager()

    class Meta:
        ordering = ["name"]
        verbose_name_plural = "quota policies"
        constraints = [
            models.CheckConstraint(
                condition=(models.Q(max_hours__isnull=True) & models.Q(max_count__isnull=True))
                | ~models.Q(period=""),
                name="quota_period_needed_for_hours_or_count",
            ),
            models.CheckConstraint(
                condition=models.Q(max_hours__isnull=True) | models.Q(max_hours__gt=0),
                name="quota_max_hours_positive",
            ),
        ]

    def __str__(self) -> str:
        return self.name


class CalendarFeed(models.Model):
    """The secret in a user's iCalendar feed URLs. Renewing it revokes the old URLs.

    Only the secret's SHA-256 is kept (``bookings.calendar.feed_token_digest``): the
    addresses are shown once, when made, and a copy of the database opens no feed.
    """

    user = models.OneToOneField(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="calendar_feed"
    )
    token_digest = models.CharField(max_length=64, unique=True)
    created_at = models.DateTimeField(auto_now=True)

    def __str__(self) -> str:
        return f"feed of {self.user}"


class SchedulerLease(ScopeTracked, models.Model):
    """A lease on the testbed's scheduler, as the portal last saw it (the mirror).

    Leases the portal made for its bookings are linked to their reservation; the others were
    made elsewhere and block portal bookings of their nodes while they hold them.
    """

    uuid = models.CharField(max_length=64, unique=True)
    name = models.CharField(max_length=200)
    start_at = models.DateTimeField()
    end_at = models.DateTimeField()
    status = models.CharField(max_length=16)
    account_name = models.CharField(max_length=150, blank=True)
    # Every node the lease holds, as the scheduler names them; ``resources`` are those of them
    # that are resources here.
    components = models.JSONField(default=list)
    resources = models.ManyToManyField(Resource, blank=True, related_name="scheduler_leases")
    reservation = models.ForeignKey(
        Reservation, null=True, blank=True, on_delete=models.SET_NULL, related_name="leases"
    )
    # Accepted or active with nodes: it keeps them from everyone else.
    holds = models.BooleanField(default=False)
    first_seen_at = models.DateTimeField(auto_now_add=True)
    seen_at = models.DateTimeField()
    # No longer listed by the scheduler (cancelled, deleted or long past).
    gone_at = models.DateTimeField(null=True, blank=True)

    objects = PeriodQuerySet["SchedulerLease"].as_manager()

    class Meta:
        ordering = ["start_at"]
        indexes = [models.Index(fields=["holds", "start_at", "end_at"])]

    def __str__(self) -> str:
        return f"lease {self.name} ({self.status})"


class SchedulerLink(models.Model):
    """How the portal's link to the testbed's scheduler is doing (one row)."""

    last_attempt_at = models.DateTimeField(null=True, blank=True)
    last_success_at = models.DateTimeField(null=True, blank=True)
    last_error = models.TextField(blank=True)
    last_error_at = models.DateTimeField(null=True, blank=True)
    # How long the last successful sweep took, and what it found.
    last_sweep_s = models.FloatField(null=True, blank=True)
    leases_seen = models.PositiveIntegerField(default=0)
    orphans_cancelled = models.PositiveIntegerField(default=0)
    bookings_flagged = models.PositiveIntegerField(default=0)

    def __str__(self) -> str:
        return "link to the testbed scheduler"


# --- What the calendar's cached answers are kept under (``core.cache``) ---------------------
#
# Each answer names the generations of what it read, and a write moves on only those of the
# rows it touched, so a booking on one node in one week leaves the other weeks, the other
# nodes' availability and the other users' lists and quotas in the cache.

# Every answer about who holds what and when, moved by every write below: the admins' lists,
# which read everyone's bookings, are kept under it.
CALENDAR = Generation("calendar")
# What every calendar answer reads besides the bookings: the resources and their groups,
# blackouts, quota policies, groups of users. Rare writes, each retiring every answer.
CALENDAR_SETUP = Generation("calendar:setup")
_WEEK = timedelta(weeks=1)
_WEEK_ZERO = datetime(1970, 1, 5, tzinfo=UTC)  # a Monday: weeks of UTC, whatever the zone
# A write spanning more weeks than this (a long lease, a bulk change) moves the setup instead
# of each week; no answer asks for more (a range is at most 62 days).
_MAX_WEEKS = 16


def calendar_weeks(start_at: datetime, end_at: datetime) -> range:
    """The weeks (counted from 1970-01-05 UTC) that ``[start_at, end_at)`` shares an instant
    with: a row overlapping a range touches one of the range's weeks."""
    first = (start_at - _WEEK_ZERO) // _WEEK
    last = (end_at - _WEEK_ZERO - timedelta(microseconds=1)) // _WEEK
    return range(first, max(first, last) + 1)


def bookings_in_week(week: int) -> Generation:
    """Every booking and lease in the week, as the busy slots show them."""
    return Generation(f"calendar:week:{week}")


def resource_in_week(resource_id: int, week: int) -> Generation:
    """One resource's holdings in the week, as its availability reads them."""
    return Generation(f"calendar:resource:{resource_id}:week:{week}")


def leases_in_week(week: int) -> Generation:
    """The scheduler's leases in the week, which every resource's availability reads."""
    return Generation(f"calendar:leases:week:{week}")


def bookings_of(user_id: int) -> Generation:
    """One user's bookings, as their lists and quota read them."""
    return Generation(f"calendar:user:{user_id}")


def _weekly(
    rows: Iterable[Mapping[str, Any]],
    of_week: Callable[[Mapping[str, Any], int], Iterable[Generation]],
) -> set[Generation]:
    """``of_week(row, week)`` for the weeks of each row's span; the setup for a span too long
    to name its weeks."""
    moved: set[Generation] = set()
    for row in rows:
        weeks = calendar_weeks(row["start_at"], row["end_at"])
        if len(weeks) > _MAX_WEEKS:
            moved.add(CALENDAR_SETUP)
        else:
            moved.update(generation for week in weeks for generation in of_week(row, week))
    return moved


def _owners(reservation_ids: Iterable[int | None]) -> set[int]:
    ids = {pk for pk in reservation_ids if pk is not None}
    if not ids:
        return set()
    return set(Reservation._base_manager.filter(pk__in=ids).values_list("owner_id", flat=True))


def _reservations_moved(rows: Sequence[Mapping[str, Any]]) -> set[Generation]:
    owners = {bookings_of(row["owner_id"]) for row in rows}
    return {CALENDAR, *owners, *_weekly(rows, lambda _, week: (bookings_in_week(week),))}


def _items_moved(rows: Sequence[Mapping[str, Any]]) -> set[Generation]:
    owners = {bookings_of(owner) for owner in _owners(row["reservation_id"] for row in rows)}
    weekly = _weekly(
        rows,
        lambda row, week: (bookings_in_week(week), resource_in_week(row["resource_id"], week)),
    )
    return {CALENDAR, *owners, *weekly}


def _leases_moved(rows: Sequence[Mapping[str, Any]]) -> set[Generation]:
    owners = {bookings_of(owner) for owner in _owners(row["reservation_id"] for row in rows)}
    weekly = _weekly(rows, lambda _, week: (bookings_in_week(week), leases_in_week(week)))
    return {CALENDAR, *owners, *weekly}


track_scoped_changes(
    Reservation,
    Scope(("owner_id", "start_at", "end_at"), _reservations_moved, (CALENDAR, CALENDAR_SETUP)),
)
track_scoped_changes(
    ReservationItem,
    Scope(
        ("reservation_id", "resource_id", "start_at", "end_at"),
        _items_moved,
        (CALENDAR, CALENDAR_SETUP),
    ),
)
track_scoped_changes(
    SchedulerLease,
    Scope(("reservation_id", "start_at", "end_at"), _leases_moved, (CALENDAR, CALENDAR_SETUP)),
)
track_changes((CALENDAR, CALENDAR_SETUP), Resource, ResourceGroup, Blackout, QuotaPolicy)
track_saves((CALENDAR, CALENDAR_SETUP), Group, User.groups.through)


def busy_generations(start_at: datetime, end_at: datetime) -> tuple[Generation, ...]:
    """What the busy slots of ``[start_at, end_at)`` are kept under."""
    return (CALENDAR_SETUP, *(bookings_in_week(w) for w in calendar_weeks(start_at, end_at)))


def availability_generations(
    resource_id: int, start_at: datetime, end_at: datetime
) -> tuple[Generation, ...]:
    """What one resource's free time in ``[start_at, end_at)`` is kept under."""
    weeks = calendar_weeks(start_at, end_at)
    return (
        CALENDAR_SETUP,
        *(resource_in_week(resource_id, w) for w in weeks),
        *(leases_in_week(w) for w in weeks),
    )


def own_bookings_generations(user: User) -> tuple[Generation, ...]:
    """What a user's own lists and quota are kept under: an admin's lists read everyone's."""
    return (CALENDAR,) if user.is_testbed_admin else (CALENDAR_SETUP, bookings_of(user.pk))


# The active quota policies, read under the booking lock on every booking: kept in the cache
# until one is written (a booking that begins in the moment between a policy's commit and this
# counter moving on still judges by the policies before it).
QUOTA_POLICIES = Generation("quota-policies")
track_changes(QUOTA_POLICIES, QuotaPolicy)
