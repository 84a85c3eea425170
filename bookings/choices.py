from django.db import models


class ResourceKind(models.TextChoices):
    MOBILE = "mobile", "mobile node"
    FIXED = "fixed", "fixed node"


class ReservationState(models.TextChoices):
    REQUESTED = "requested", "awaiting approval"
    CONFIRMED = "confirmed", "confirmed"
    REJECTED = "rejected", "rejected"
    CANCELLED = "cancelled", "cancelled"
    COMPLETED = "completed", "completed"


# A requested reservation holds its slot while an admin decides, so nobody else can take it.
RESERVATION_ACTIVE_STATES = (ReservationState.REQUESTED, ReservationState.CONFIRMED)
# Withdrawn: the slot (and a lease of fixed nodes with it) is given back.
RESERVATION_WITHDRAWN_STATES = (ReservationState.REJECTED, ReservationState.CANCELLED)
# What counts against a quota: everything not withdrawn.
RESERVATION_COUNTED_STATES = (
    ReservationState.REQUESTED,
    ReservationState.CONFIRMED,
    ReservationState.COMPLETED,
)


class QuotaPeriod(models.TextChoices):
    DAY = "day", "day"
    WEEK = "week", "week (Monday to Sunday)"
    MONTH = "month", "calendar month"


class BookedVia(models.TextChoices):
    PORTAL = "portal", "the portal (pages or API)"
    SCHEDULER = "scheduler", "the testbed scheduler's lease API"


class Channel(models.TextChoices):
    """Through what door someone changed a booking: its owner is told, its audit row says."""

    WEB = "web", "on the portal's pages"
    API = "api", "through the portal's REST API"
    LEASE_API = "lease_api", "through the testbed scheduler's lease API"
    ADMIN = "admin", "in the portal's admin site"
    # The REST API as the ``amazing`` command calls it (it says so in a header).
    CLI = "cli", "with the amazing command"
    # Booked by the queue for its owner, in the first slot that fitted (portal/queue).
    QUEUE = "queue", "by the queue"
    # A robot's daily self-check, booked for the admin who scheduled it.
    SCHEDULE = "schedule", "by a daily schedule"
