"""The queue's allocator: one pass books every waiting request whose first slot lies within
the horizon, in fair-share order, through the same service as every booking
(``portal.runs.services.reservations.reservation_create``), which checks every rule under its
locks; it expires what can no longer be met. It holds only the request it is booking
(``SELECT … FOR UPDATE SKIP LOCKED``): two allocators never book one request twice, and the
booking's lock and constraint keep them from booking one slot twice.

Passes take turns (:func:`queue_allocate`, a session's advisory lock held for the pass): two
passes at once would each skip the request the other holds and book the next in line, so
that the slots went out of fair-share order. A pass woken meanwhile waits and then books
what the first left, so no wake is lost."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from datetime import datetime, timedelta

from django.conf import settings
from django.db import transaction
from django.utils import timezone

from bookings.choices import Channel
from core.audit.services import audit_record
from core.errors import DomainError
from core.sql import advisory_key, advisory_session_lock
from portal.queue.events import queue_request_event_record
from portal.queue.models import QueueRequest, RequestState
from portal.queue.selectors import (
    queue_control,
    request_resources,
    request_search_period,
    request_slot,
    waiting_in_order,
)
from portal.queue.slots import Period
from portal.runs.services import reservations as with_run

logger = logging.getLogger(__name__)

# How often one pass tries a request whose slot was taken between the look and the booking.
BOOK_ATTEMPTS = 3
# The allocator's turn (``queue_allocate``).
PASS_LOCK = advisory_key(b"queue-allocate-pass")


@dataclass
class Pass:
    """What one pass of the allocator did."""

    booked: list[int]
    expired: list[int]
    waiting: int
    paused: bool = False


def queue_allocate(*, now: datetime | None = None) -> Pass:
    """One pass, in its turn: no other pass runs meanwhile (see the module's text)."""
    with advisory_session_lock(PASS_LOCK):
        return allocation_pass(now=now)


def allocation_pass(*, now: datetime | None = None) -> Pass:
    """One pass: expire what can no longer be met, then book every waiting request whose
    first slot lies within the horizon, in fair-share order (the order is read again after
    each booking: the use it adds counts at once). Safe beside another pass (nothing is
    booked twice), fair only alone: :func:`queue_allocate` takes the turn."""
    now = now or timezone.now()
    if queue_control().paused:
        waiting = QueueRequest.objects.filter(state=RequestState.WAITING).count()
        return Pass([], [], waiting, paused=True)
    expired = _expire(now)
    booked: list[int] = []
    tried: set[int] = set()
    while True:
        order = [w.request for w in waiting_in_order(now=now) if w.request.pk not in tried]
        if not order:
            break
        for request in order:
            tried.add(request.pk)
            if _book(request, now=now):
                booked.append(request.pk)
                break  # the order changes with the use this booking adds
        else:
            break
    waiting = QueueRequest.objects.filter(state=RequestState.WAITING).count()
    return Pass(booked, expired, waiting)


def _held_if_waiting(request: QueueRequest) -> QueueRequest | None:
    """The request's row, locked until the transaction ends, if it still waits and no other
    allocator holds it (then None: that one does what is to be done)."""
    return (
        QueueRequest.objects.select_for_update(skip_locked=True)
        .filter(pk=request.pk, state=RequestState.WAITING)
        .first()
    )


def _expire(now: datetime) -> list[int]:
    expired = []
    for request in QueueRequest.objects.filter(state=RequestState.WAITING):
        if request_search_period(request, now=now) is not None:
            continue
        with transaction.atomic():
            locked = _held_if_waiting(request)
            if locked is None:
                continue
            last = f" Last finding: {locked.reason}" if locked.reason else ""
            locked.state = RequestState.EXPIRED
            locked.reason = (
                f"No slot of {locked.duration_s} s could be booked before its latest end "
                f"({timezone.localtime(locked.latest_end_at):%Y-%m-%d %H:%M}).{last}"
            )
            locked.save(update_fields=["state", "reason", "updated_at"])
            audit_record(actor=None, action="queue.expire", target=locked, reason=locked.reason)
            queue_request_event_record("queue.expired", locked)
            expired.append(locked.pk)
    return expired


def _book(request: QueueRequest, *, now: datetime) -> bool:
    """Book ``request`` in its first slot within the horizon, holding it against another
    allocator; say why it waits otherwise."""
    horizon = now + timedelta(seconds=settings.QUEUE_HORIZON_S)
    with transaction.atomic():
        locked = _held_if_waiting(request)
        if locked is None:
            return False  # another allocator holds it, or it has just changed
        resources = request_resources(request)
        why = ""
        tried: Period | None = None
        for _ in range(BOOK_ATTEMPTS):
            slot = request_slot(request, now=now, until=horizon)
            if slot is None:
                why = _why_no_slot(request, now=now, horizon=horizon)
                break
            if slot == tried:
                break  # refused again in the same slot: not a race, a rule (the last why)
            tried = slot
            try:
                with transaction.atomic():
                    reservation = with_run.reservation_create(
                        owner=request.owner,
                        resources=resources,
                        start_at=slot[0],
                        end_at=slot[1],
                        experiment=request.experiment,
                        title=request.title,
                        by=request.owner,
                        now=now,
                        via=Channel.QUEUE,
                    )
            except DomainError as exc:
                # Taken between the look and the booking (look again), or a rule that holds
                # it back for now (a quota): said on the request, tried again next pass.
                why = exc.message
                logger.info("queue request %s: slot at %s refused (%s)", request.pk, slot[0], why)
                continue
            locked.state = RequestState.BOOKED
            locked.reservation = reservation
            locked.reason = ""
            locked.save(update_fields=["state", "reservation", "reason", "updated_at"])
            audit_record(
                actor=None,
                action="queue.book",
                target=locked,
                reservation=reservation.pk,
                start_at=slot[0].isoformat(),
            )
            queue_request_event_record("queue.booked", locked)
            return True
        if why != locked.reason:
            locked.reason = why
            locked.save(update_fields=["reason", "updated_at"])
        return False


def _why_no_slot(request: QueueRequest, *, now: datetime, horizon: datetime) -> str:
    if request.earliest_at >= horizon:
        return (
            f"Its earliest start is beyond the queue's horizon "
            f"({settings.QUEUE_HORIZON_S / 86400:g} days); it is booked once the horizon "
            "reaches it."
        )
    beyond = request_slot(request, now=now)
    if beyond is not None:
        return (
            f"No free slot within the queue's horizon ({settings.QUEUE_HORIZON_S / 86400:g} "
            f"days); the first after it starts {timezone.localtime(beyond[0]):%Y-%m-%d %H:%M}."
        )
    return "No free slot of its length in its allowed hours before its latest end yet."
