"""E-mails about reservations: what happened, to whom, in the testbed's words."""

from __future__ import annotations

import logging

from django.conf import settings
from django.core.mail import send_mail
from django.utils import timezone

from bookings.choices import Channel
from bookings.models import Blackout, Reservation
from core.accounts.models import User

logger = logging.getLogger(__name__)

SUBJECTS = {
    "confirmed": "Booking confirmed: {what}",
    "requested": "Booking request received: {what}",
    "approved": "Booking approved: {what}",
    "rejected": "Booking request rejected: {what}",
    "cancelled": "Your booking was cancelled by {who}: {what}",
    "blackout_conflict": "Maintenance overlaps a booking: {what}",
    "reminder": "Reminder: {what} starts soon",
    "lease_conflict": "A lease on the testbed scheduler overlaps a booking: {what}",
    "lease_vanished": "A booking lost its lease on the testbed scheduler: {what}",
}
# Kinds the admins are told of too: pending requests and bookings something went wrong with.
ADMINS_TOO = ("blackout_conflict", "requested", "lease_conflict", "lease_vanished")


def _describe(reservation: Reservation) -> str:
    names = ", ".join(item.resource.name for item in reservation.items.select_related("resource"))
    start = timezone.localtime(reservation.start_at)
    end = timezone.localtime(reservation.end_at)
    return f"{names} on {start:%Y-%m-%d %H:%M}–{end:%H:%M} ({settings.TIME_ZONE})"


def _canceller(reservation: Reservation) -> str:
    """Who cancelled, as the owner knows them: their name, and what they are to the testbed."""
    user = reservation.cancelled_by
    if user is None:
        return "someone no longer registered"
    name = user.get_full_name() or user.get_username()
    if user.has_staff_role:
        return f"{name} (an admin)"
    if user.has_perm("bookings.lease_inbound"):
        return f"{name} (the testbed scheduler's account)"
    return name


def reservation_message(
    kind: str,
    reservation: Reservation,
    *,
    blackout: Blackout | None = None,
    via: str = "",
) -> tuple[str, str]:
    what = _describe(reservation)
    who = _canceller(reservation) if kind == "cancelled" else ""
    lines = [f"Hello {reservation.owner.get_username()},", ""]
    if kind == "confirmed":
        lines.append(f"your booking of {what} is confirmed.")
    elif kind == "requested":
        lines.append(f"your booking of {what} waits for an admin's approval; you will be told.")
    elif kind == "approved":
        lines.append(f"your booking of {what} was approved.")
    elif kind == "rejected":
        lines.append(f"your booking request for {what} was rejected: {reservation.decision_reason}")
    elif kind == "cancelled":
        through = f" {Channel(via).label}" if via in Channel.values else ""
        reason = f": {reservation.cancel_reason}" if reservation.cancel_reason else "."
        lines.append(f"{who} cancelled your booking of {what}{through}{reason}")
    elif kind == "blackout_conflict" and blackout is not None:
        lines.append(
            f"a maintenance window, “{blackout.reason}”, overlaps your booking of {what}. "
            "An admin will contact you; you may also move or cancel the booking."
        )
    elif kind in ("lease_conflict", "lease_vanished"):
        lines.append(
            f"there is a problem with your booking of {what}: {reservation.conflict} "
            "An admin will contact you; you may also move or cancel the booking."
        )
    elif kind == "reminder":
        lines.append(f"your booking of {what} starts soon.")
    if reservation.title:
        lines += ["", f"Experiment: {reservation.title}"]
    lines += ["", "— AMazING testbed"]
    return SUBJECTS[kind].format(what=what, who=who), "\n".join(lines)


def reservation_notify(
    kind: str, reservation_id: int, *, blackout_id: int | None = None, via: str = ""
) -> int:
    """Send the e-mail of ``kind``; returns how many were sent. ``via``: the
    :class:`~bookings.choices.Channel` a change came through, when it matters."""
    reservation = Reservation.objects.select_related("owner", "cancelled_by").get(pk=reservation_id)
    blackout = Blackout.objects.filter(pk=blackout_id).first() if blackout_id else None
    subject, body = reservation_message(kind, reservation, blackout=blackout, via=via)
    recipients = [reservation.owner.email] if reservation.owner.email else []
    if kind in ADMINS_TOO:
        # Admins learn of pending requests and of bookings a maintenance window hits.
        recipients += list(
            User.objects.filter(is_staff=True, is_active=True)
            .exclude(email="")
            .values_list("email", flat=True)
        )
    recipients = sorted(set(recipients))
    if not recipients:
        logger.warning("reservation %s: no address to send %r to", reservation_id, kind)
        return 0
    return send_mail(subject, body, settings.DEFAULT_FROM_EMAIL, recipients)
