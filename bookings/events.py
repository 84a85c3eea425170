"""A reservation's events (``core.events``), written in the transaction of the change: the
reservation as it is now, and who changed it through which door, or what stands in its way."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

from bookings.models import Reservation
from core.events.services import event_record

# What stands in a reservation's way (``reservation.flagged``).
Problem = Literal["maintenance", "lease_conflict", "lease_vanished"]


SUBJECT_PREFIX = "reservation:"


def subject_of(reservation_id: int) -> str:
    return f"{SUBJECT_PREFIX}{reservation_id}"


def _described(reservation: Reservation, resources: Sequence[str] | None) -> dict[str, Any]:
    names = (
        list(resources)
        if resources is not None
        else list(
            reservation.items.order_by("resource__name").values_list("resource__name", flat=True)
        )
    )
    return {
        "reservation": reservation.pk,
        "state": str(reservation.state),
        "resources": names,
        "start_at": reservation.start_at.isoformat(),
        "end_at": reservation.end_at.isoformat(),
        "title": reservation.title,
    }


def reservation_event_record(
    type: str,
    reservation: Reservation,
    *,
    by: str | None,
    via: str,
    resources: Sequence[str] | None = None,
) -> None:
    """``type``'s event: ``by`` the username of who made the change (None: the system),
    ``via`` the door it came through ("" when not said)."""
    event_record(
        subject=subject_of(reservation.pk),
        type=type,
        owner_id=reservation.owner_id,
        payload={**_described(reservation, resources), "via": via, "by": by},
    )


def reservation_flagged_record(
    reservation: Reservation, *, problem: Problem, note: str, blackout_id: int | None = None
) -> None:
    """``reservation.flagged``: ``note`` is what its owner and the admins are told."""
    event_record(
        subject=subject_of(reservation.pk),
        type="reservation.flagged",
        owner_id=reservation.owner_id,
        payload={
            **_described(reservation, None),
            "problem": problem,
            "note": note,
            "blackout": blackout_id,
        },
    )
