"""The bookings' reactions to events (``core.events.dispatch``): the e-mails about a
reservation, to its owner (and to the admins for a request and a problem), and the count of
robots' holds. Imported when the app is ready (``BookingsConfig.ready``)."""

from __future__ import annotations

import logging

from bookings import notifications
from bookings.models import Reservation
from core.audit.counters import event_count
from core.events.dispatch import handler
from core.events.models import Event

logger = logging.getLogger(__name__)

# The mail of each flagged problem (bookings.notifications).
_FLAGGED = {
    "maintenance": "blackout_conflict",
    "lease_conflict": "lease_conflict",
    "lease_vanished": "lease_vanished",
}


def mail_kind(event: Event) -> str | None:
    """Which of ``bookings.notifications``'s e-mails an event is, or None for none."""
    payload = event.payload
    if event.type == "reservation.created":
        return "requested" if payload["state"] == "requested" else "confirmed"
    if event.type in ("reservation.approved", "reservation.rejected"):
        return event.type.removeprefix("reservation.")
    if event.type == "reservation.cancelled":
        # Its owner knows what they did themselves; told when someone else did it.
        owner = event.owner.get_username() if event.owner is not None else None
        return "cancelled" if payload["by"] != owner else None
    if event.type == "reservation.starting_soon":
        return "reminder"
    if event.type == "reservation.flagged":
        return _FLAGGED[payload["problem"]]
    return None


@handler(
    "reservation-mail",
    types=[
        "reservation.created",
        "reservation.approved",
        "reservation.rejected",
        "reservation.cancelled",
        "reservation.starting_soon",
        "reservation.flagged",
    ],
)
def reservation_mail(event: Event) -> None:
    kind = mail_kind(event)
    if kind is None:
        return
    payload = event.payload
    try:
        notifications.reservation_notify(
            kind,
            payload["reservation"],
            blackout_id=payload.get("blackout"),
            via=payload.get("via", ""),
        )
    except Reservation.DoesNotExist:
        # Deleted with its owner since: no one to tell, and the events after it must go on.
        logger.info("reservation %s is gone: no %r mail", payload["reservation"], kind)


@handler("robot-hold-count", types=["robot.held"])
def robot_hold_count(event: Event) -> None:
    """``amazing_robot_holds_total``: counted in the pass's transaction with its cursor, so once
    per hold."""
    event_count("robot_holds", resource=event.payload["resource"])
