"""The fixed nodes' leases on the testbed's scheduler, seen from the portal.

The scheduler (``settings.SCHEDULER``; ``bookings/scheduler/`` speaks to it) owns the fixed
nodes. A booking that holds any of them holds one lease with all of them, made inside the
booking (``reservation_create``): the lease first, named after the reservation's public id,
then the portal's commit; on a failure in between the lease is cancelled at once, and if the
process died in between, :func:`scheduler_sweep` finds the orphan and cancels it — or, sooner,
the next booking of one of its nodes (:func:`leases_clear_own_orphans`: a client's retry of
the killed request succeeds at once instead of being refused by its own first attempt).

The sweep also mirrors the leases made elsewhere (they block portal bookings of their nodes,
``bookings.rules``), flags portal bookings that a lease appeared over or whose own lease
vanished, and records the link's health (:class:`SchedulerLink`).

While a booking holds its lease but has not committed, a PostgreSQL advisory lock named after
its public id is held by its transaction; the sweep cancels a lease without a booking only
when it can take that lock (so never one still being booked). On SQLite, which has no such
locks, it waits for ``SCHEDULER_ORPHAN_GRACE_S`` instead.
"""

from __future__ import annotations

import logging
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta

from django.conf import settings
from django.db import connection, transaction
from django.utils import timezone

from bookings.choices import (
    RESERVATION_ACTIVE_STATES,
    RESERVATION_WITHDRAWN_STATES,
    ResourceKind,
)
from bookings.events import Problem, reservation_flagged_record
from bookings.models import Reservation, Resource, SchedulerLease, SchedulerLink
from bookings.scheduler import (
    ALL_STATUSES,
    Lease,
    Scheduler,
    SchedulerConflict,
    SchedulerError,
    SchedulerUnavailable,
    build_scheduler,
)
from core import sql
from core.audit.counters import event_count
from core.audit.text import storable_text
from core.errors import Conflict, DomainError
from core.events.services import event_record

logger = logging.getLogger(__name__)

LEASE_NAME_PREFIX = "amazing-reservation-"
# How far back and ahead the sweep mirrors leases: the calendar's reach.
MIRROR_PAST = timedelta(days=1)
MIRROR_AHEAD = timedelta(days=62)


class SchedulerDown(DomainError):
    """The scheduler did not answer (or not in time): nothing was booked or changed."""

    http_status = 503
    code = "scheduler_unavailable"


class SchedulerRefused(DomainError):
    """The scheduler answered, but not with a lease (credentials, configuration, protocol)."""

    http_status = 502
    code = "scheduler_refused"


def scheduler_enabled() -> bool:
    return settings.SCHEDULER is not None


def scheduler_client() -> Scheduler:
    assert settings.SCHEDULER is not None
    return build_scheduler(settings.SCHEDULER)


def scheduler_owned(resources: Sequence[Resource]) -> list[Resource]:
    """The resources the scheduler books, not the portal (by default every fixed node)."""
    config = settings.SCHEDULER
    if config is None:
        return []
    return [
        r
        for r in resources
        if config.owns(resource_name=r.name, is_fixed_node=r.kind == ResourceKind.FIXED)
    ]


def lease_name_for(public_id: uuid.UUID) -> str:
    return f"{LEASE_NAME_PREFIX}{public_id}"


def public_id_of(lease_name: str) -> uuid.UUID | None:
    """The reservation a lease was made for, if the portal made it."""
    if not lease_name.startswith(LEASE_NAME_PREFIX):
        return None
    try:
        return uuid.UUID(lease_name.removeprefix(LEASE_NAME_PREFIX))
    except ValueError:
        return None


def _domain_error(exc: SchedulerError, what: str) -> DomainError:
    if isinstance(exc, SchedulerConflict):
        nodes = ", ".join(exc.node_names) or "a node"
        detail = f" ({exc.reason})" if exc.reason else ""
        return Conflict.on_field(
            "resources", f"The testbed scheduler refused the lease: {nodes} is taken{detail}."
        )
    if isinstance(exc, SchedulerUnavailable):
        return SchedulerDown(
            f"The testbed scheduler did not answer, so nothing was {what}. Try again in a "
            f"moment. ({exc.message})"
        )
    return SchedulerRefused(f"The testbed scheduler refused to {what}: {exc.message}")


# --- Leases for portal bookings --------------------------------------------------------------


def booking_guard(public_id: uuid.UUID) -> None:
    """Mark ``public_id`` as being booked until the current transaction ends (PostgreSQL;
    SQLite's writing transactions already run one at a time)."""
    sql.advisory_xact_lock(sql.advisory_key(public_id.bytes))


def _not_being_booked(public_id: uuid.UUID) -> bool:
    """True when no transaction is booking ``public_id`` right now (PostgreSQL only)."""
    # A transaction of its own, so that the lock, if taken, is let go at once.
    with transaction.atomic():
        return sql.try_advisory_xact_lock(sql.advisory_key(public_id.bytes))


def _leases_listed(*, start_at: datetime, end_at: datetime) -> list[Lease]:
    with scheduler_client() as scheduler:
        return scheduler.list_leases(window_start=start_at, window_end=end_at)


def leases_refresh(*, start_at: datetime, end_at: datetime) -> list[Lease]:
    """The scheduler's leases over ``[start_at, end_at)`` now (before a booking), so that a
    lease made elsewhere a moment ago refuses the booking with its name; mirrored too (a
    refused booking's transaction may take that back: the sweep mirrors them again)."""
    listed_at = timezone.now()
    try:
        leases = _leases_listed(start_at=start_at, end_at=end_at)
    except SchedulerError as exc:
        raise _domain_error(exc, "booked") from exc
    _mirror(leases, now=listed_at, window=(start_at, end_at))
    return leases


def leases_for_check(*, start_at: datetime, end_at: datetime) -> tuple[list[Lease] | None, str]:
    """The scheduler's leases over ``[start_at, end_at)``, asked now as booking asks it, for the
    live check (nothing is mirrored: a check changes nothing).

    When the scheduler cannot be reached: None (the mirror of its last sync speaks instead)
    and a sentence that says so. One that answers but refuses is the error booking would get.
    """
    try:
        return _leases_listed(start_at=start_at, end_at=end_at), ""
    except SchedulerUnavailable as exc:
        logger.warning("scheduler unreachable for a booking check, mirror used: %s", exc)
        link = SchedulerLink.objects.filter(pk=1).first()
        synced = link.last_success_at if link is not None else None
        since = (
            f"as of {timezone.localtime(synced):%Y-%m-%d %H:%M}"
            if synced is not None
            else "as last seen"
        )
        return None, (
            f"The testbed scheduler did not answer: its leases are shown {since}. Booking asks "
            "it again."
        )
    except SchedulerError as exc:
        raise SchedulerRefused(
            f"The testbed scheduler refused to list its leases: {exc.message}"
        ) from exc


def lease_take(
    *, public_id: uuid.UUID, start_at: datetime, end_at: datetime, resources: Sequence[Resource]
) -> Lease:
    """One lease holding every one of ``resources`` for the booking, or a domain error."""
    config = settings.SCHEDULER
    assert config is not None
    try:
        with scheduler_client() as scheduler:
            lease = scheduler.create_lease(
                name=lease_name_for(public_id),
                valid_from=start_at,
                valid_until=end_at,
                component_names=[r.name for r in resources],
            )
    except SchedulerError as exc:
        raise _domain_error(exc, "booked") from exc
    logger.info("lease %s taken for reservation %s", lease.uuid, public_id)
    return lease


def leases_clear_own_orphans(
    leases: Sequence[Lease],
    *,
    resources: Sequence[Resource],
    start_at: datetime,
    end_at: datetime,
    now: datetime,
) -> list[Lease]:
    """``leases`` (as listed before a booking) without the portal's own orphans in its way,
    which are cancelled here: called under the booking's locks.

    A booking killed between its lease and its commit (the web process killed, a client's
    retry already on its way) leaves its lease on the scheduler. The retry would be refused
    by that lease until the next sweep; instead, a lease that is the portal's (its name and
    account), has no booking holding it, and is not being booked (its advisory lock free) is
    cancelled now, by the same test the sweep applies, and the booking goes on. A lease the
    scheduler would not cancel stays in the list, and refuses the booking as before.
    """
    wanted = {r.name for r in resources}
    standing = []
    for lease in leases:
        in_the_way = (
            lease.holds_nodes
            and wanted.intersection(lease.component_names)
            and lease.overlaps(start=start_at, end=end_at)
        )
        if not in_the_way or not _orphan(lease, now=now, booking=True):
            standing.append(lease)
            continue
        try:
            with scheduler_client() as scheduler:
                scheduler.cancel_lease(uuid=lease.uuid)
        except SchedulerError as exc:
            logger.warning("orphan lease %s (%s) not cancelled: %s", lease.uuid, lease.name, exc)
            standing.append(lease)
            continue
        SchedulerLease.objects.filter(uuid=lease.uuid).update(holds=False, status="cancelled")
        logger.warning(
            "orphan lease %s (%s) cancelled: it stood in the way of a new booking",
            lease.uuid,
            lease.name,
        )
    return standing


def lease_record(*, lease: Lease, reservation: Reservation, resources: Sequence[Resource]) -> None:
    """Keep the booking's own lease in the mirror, linked to it."""
    now = timezone.now()
    row, _ = SchedulerLease.objects.update_or_create(
        uuid=lease.uuid,
        defaults={
            "name": lease.name,
            "start_at": lease.valid_from,
            "end_at": lease.valid_until,
            "status": lease.status.value,
            "account_name": lease.account_name,
            "components": list(lease.component_names),
            "reservation": reservation,
            "holds": lease.holds_nodes,
            "seen_at": now,
            "gone_at": None,
        },
    )
    row.resources.set(resources)


def lease_release(*, lease_uuid: str) -> None:
    """Cancel a lease the portal no longer needs; failures are left to the sweep."""
    try:
        with scheduler_client() as scheduler:
            scheduler.cancel_lease(uuid=lease_uuid)
    except SchedulerError as exc:
        logger.warning("lease %s not cancelled (the sweep retries): %s", lease_uuid, exc)
        return
    SchedulerLease.objects.filter(uuid=lease_uuid).update(holds=False, status="cancelled")
    logger.info("lease %s cancelled", lease_uuid)


def lease_move(*, lease_uuid: str, start_at: datetime, end_at: datetime) -> Lease:
    try:
        with scheduler_client() as scheduler:
            lease = scheduler.move_lease(uuid=lease_uuid, valid_from=start_at, valid_until=end_at)
    except SchedulerError as exc:
        raise _domain_error(exc, "moved") from exc
    SchedulerLease.objects.filter(uuid=lease_uuid).update(
        start_at=lease.valid_from, end_at=lease.valid_until, status=lease.status.value
    )
    return lease


# --- The sweep: mirror, reconcile, health ----------------------------------------------------


@dataclass(frozen=True)
class SweepResult:
    leases_seen: int
    orphans_cancelled: int
    # (its problem, reservation id) for each booking flagged by this sweep.
    notices: tuple[tuple[str, int], ...]


# The advisory lock that lets one mirror run at a time (PostgreSQL).
MIRROR_LOCK_KEY = sql.advisory_key(b"leasemir")


def _mirror(leases: Sequence[Lease], *, now: datetime, window: tuple[datetime, datetime]) -> None:
    """Upsert what the scheduler listed at ``now``; what it no longer lists in the window is
    gone — unless a newer look (another process's) saw it after ``now``.

    One mirror at a time, until its transaction ends: a booking mirrors inside its own
    transaction (the API's, with the idempotency key), the sweep in its; each locks many lease
    rows in the order the scheduler listed them, and two at once deadlocked (a booking
    answered 500 while the sweep ran)."""
    with transaction.atomic():
        sql.advisory_xact_lock(MIRROR_LOCK_KEY)
        _mirror_locked(leases, now=now, window=window)


def _mirror_locked(
    leases: Sequence[Lease], *, now: datetime, window: tuple[datetime, datetime]
) -> None:
    by_name = {r.name: r for r in Resource.objects.all()}
    own = {
        str(public_id): pk
        for public_id, pk in Reservation.objects.exclude(lease_uuid="").values_list(
            "public_id", "pk"
        )
    }
    seen = []
    for lease in leases:
        public_id = public_id_of(lease.name)
        row, _ = SchedulerLease.objects.update_or_create(
            uuid=lease.uuid,
            defaults={
                "name": lease.name,
                "start_at": lease.valid_from,
                "end_at": lease.valid_until,
                "status": lease.status.value,
                "account_name": lease.account_name,
                "components": list(lease.component_names),
                "holds": lease.holds_nodes,
                "seen_at": now,
                "gone_at": None,
            },
        )
        # A booking committed after this look began is linked already: never unlink it.
        reservation_id = own.get(str(public_id)) if public_id else None
        if reservation_id is not None and row.reservation_id != reservation_id:
            SchedulerLease.objects.filter(pk=row.pk).update(reservation_id=reservation_id)
        row.resources.set([by_name[n] for n in lease.component_names if n in by_name])
        seen.append(lease.uuid)
    SchedulerLease.objects.overlapping(*window).filter(
        gone_at__isnull=True, seen_at__lt=now
    ).exclude(uuid__in=seen).update(gone_at=now, holds=False)


def _writes_one_at_a_time() -> bool:
    """SQLite whose transactions begin IMMEDIATE (the settings' choice): inside one, no other
    transaction writes, so no booking is between its lease and its commit."""
    options = connection.settings_dict.get("OPTIONS", {})
    return (
        sql.is_sqlite()
        and connection.in_atomic_block
        and options.get("transaction_mode") == "IMMEDIATE"
    )


def _orphan(lease: Lease, *, now: datetime, booking: bool = False) -> bool:
    """A lease the portal made whose booking is not (or no longer) holding it.

    ``booking``: asked from inside a booking's transaction, which on SQLite excludes every
    other booking, so that no grace is needed there.
    """
    public_id = public_id_of(lease.name)
    config = settings.SCHEDULER
    if public_id is None or config is None or lease.account_name != config.account_name:
        return False
    if not lease.status.holds_nodes and lease.status.value != "pending":
        return False
    # A booking holds its lease to the end of its slot unless withdrawn: one whose run
    # completed early keeps its fixed nodes (the experiment on them may go on).
    held = (
        Reservation.objects.filter(public_id=public_id, lease_uuid=lease.uuid)
        .exclude(state__in=RESERVATION_WITHDRAWN_STATES)
        .exists()
    )
    if held:
        return False
    if sql.is_postgresql():
        return _not_being_booked(public_id)
    if booking and _writes_one_at_a_time():
        return True
    first_seen = (
        SchedulerLease.objects.filter(uuid=lease.uuid)
        .values_list("first_seen_at", flat=True)
        .first()
    )
    grace = timedelta(seconds=settings.SCHEDULER_ORPHAN_GRACE_S)
    return first_seen is not None and now - first_seen >= grace


def _flag(reservation: Reservation, note: str, kind: Problem) -> list[tuple[str, int]]:
    """Flag a booking once per cause, with its event (its owner and the admins are told:
    ``bookings.handlers``)."""
    if reservation.conflict == note:
        return []
    Reservation.objects.filter(pk=reservation.pk).update(conflict=note)
    reservation_flagged_record(reservation, problem=kind, note=note)
    logger.warning("reservation %s flagged: %s", reservation.pk, note)
    return [(kind, reservation.pk)]


def _flag_late_conflicts(leases: Sequence[Lease], *, now: datetime) -> list[tuple[str, int]]:
    """Portal bookings that a lease made elsewhere now overlaps on one of their nodes."""
    flagged: list[tuple[str, int]] = []
    local = timezone.localtime
    for lease in leases:
        if not lease.holds_nodes or public_id_of(lease.name) is not None:
            continue
        clashing = (
            Reservation.objects.overlapping(lease.valid_from, lease.valid_until)
            .filter(
                state__in=RESERVATION_ACTIVE_STATES,
                end_at__gt=now,
                items__resource__name__in=lease.component_names,
            )
            .distinct()
        )
        for reservation in clashing:
            note = (
                f"A lease on the testbed scheduler, “{lease.name}” ({lease.account_name}), "
                f"holds {', '.join(lease.component_names)} from "
                f"{local(lease.valid_from):%Y-%m-%d %H:%M} to "
                f"{local(lease.valid_until):%Y-%m-%d %H:%M}, over this booking."
            )
            flagged += _flag(reservation, note, "lease_conflict")
    return flagged


def _flag_vanished(
    leases: Sequence[Lease], *, now: datetime, window: tuple[datetime, datetime]
) -> list[tuple[str, int]]:
    """Upcoming portal bookings whose own lease the scheduler no longer holds.

    The listing was asked for after ``now``; a booking made or moved meanwhile took a lease the
    listing may not show, and recorded it with a newer look (``lease_record``'s ``seen_at``):
    such a lease is not gone, as in :func:`_mirror`."""
    holding = {lease.uuid for lease in leases if lease.holds_nodes}
    seen_later = set(
        SchedulerLease.objects.filter(seen_at__gt=now, gone_at__isnull=True).values_list(
            "uuid", flat=True
        )
    )
    flagged: list[tuple[str, int]] = []
    for reservation in (
        Reservation.objects.overlapping(*window)
        .filter(state__in=RESERVATION_ACTIVE_STATES, end_at__gt=now)
        .exclude(lease_uuid="")
    ):
        if reservation.lease_uuid in holding or reservation.lease_uuid in seen_later:
            continue
        note = (
            "Its lease on the testbed scheduler is gone: the fixed nodes may be booked by "
            "someone else. Book them again or cancel."
        )
        flagged += _flag(reservation, note, "lease_vanished")
    return flagged


def scheduler_sweep(*, now: datetime | None = None) -> SweepResult | None:
    """Mirror, reconcile and record the link's health; None when no scheduler is set up."""
    if not scheduler_enabled():
        return None
    now = now or timezone.now()
    started_s = time.monotonic()
    link, _ = SchedulerLink.objects.get_or_create(pk=1)
    link.last_attempt_at = now
    window = (now - MIRROR_PAST, now + MIRROR_AHEAD)
    try:
        with scheduler_client() as scheduler:
            leases = scheduler.list_leases(
                window_start=window[0], window_end=window[1], statuses=ALL_STATUSES
            )
            with transaction.atomic():
                _mirror(leases, now=now, window=window)
            orphans = [lease for lease in leases if _orphan(lease, now=now)]
            for lease in orphans:
                scheduler.cancel_lease(uuid=lease.uuid)
                SchedulerLease.objects.filter(uuid=lease.uuid).update(
                    holds=False, status="cancelled"
                )
                logger.warning("orphan lease %s (%s) cancelled", lease.uuid, lease.name)
    except SchedulerError as exc:
        was_down = _link_down(link)
        link.last_error = exc.message
        link.last_error_at = now
        with transaction.atomic():
            link.save()
            if not was_down:
                since = {"since": link.last_success_at.isoformat()} if link.last_success_at else {}
                _link_event("scheduler.link_down", error=storable_text(exc.message), **since)
        event_count("scheduler_link_errors")
        logger.warning("scheduler sweep failed: %s", exc)
        return None
    with transaction.atomic():
        live = [lease for lease in leases if lease.uuid not in {o.uuid for o in orphans}]
        notices = _flag_late_conflicts(live, now=now) + _flag_vanished(live, now=now, window=window)
    was_down = _link_down(link)
    link.last_success_at = now
    link.last_sweep_s = time.monotonic() - started_s
    link.leases_seen = len(leases)
    link.orphans_cancelled += len(orphans)
    link.bookings_flagged += len(notices)
    with transaction.atomic():
        link.save()
        if was_down:
            _link_event("scheduler.link_up", error="")
    return SweepResult(len(leases), len(orphans), tuple(notices))


def _link_down(link: SchedulerLink) -> bool:
    """The link's last sweep failed (its error is newer than its last success)."""
    return link.last_error_at is not None and (
        link.last_success_at is None or link.last_error_at > link.last_success_at
    )


def _link_event(type: str, **payload: str) -> None:
    """The link going down or coming back, for staff (``core.events``): once per change,
    in the transaction that records it (sweeps run one at a time, from beat)."""
    event_record(subject="scheduler", type=type, owner_id=None, payload=payload)


def scheduler_link_status(*, now: datetime | None = None) -> dict[str, object]:
    """For /healthz and the admins' page: is the link to the testbed scheduler working?"""
    if not scheduler_enabled():
        return {"configured": False}
    now = now or timezone.now()
    link = SchedulerLink.objects.filter(pk=1).first()
    last_success = link.last_success_at if link else None
    lag_s = None if last_success is None else (now - last_success).total_seconds()
    stale_after_s = max(60.0, 3 * settings.SCHEDULER_SYNC_INTERVAL_S)
    return {
        "configured": True,
        "ok": lag_s is not None and lag_s <= stale_after_s,
        "last_sync_age_s": None if lag_s is None else round(lag_s, 1),
        "last_error": link.last_error if link else "",
        "last_error_at": link.last_error_at.isoformat() if link and link.last_error_at else None,
    }


def scheduler_overview(*, now: datetime) -> dict[str, object]:
    """The admins' page: the link, the portal's leases (in step with their bookings or not),
    and the leases made elsewhere that hold nodes."""
    own = []
    for reservation in (
        Reservation.objects.filter(state__in=RESERVATION_ACTIVE_STATES, end_at__gt=now)
        .exclude(lease_uuid="")
        .select_related("owner")
        .order_by("start_at")[:200]
    ):
        lease = SchedulerLease.objects.filter(uuid=reservation.lease_uuid).first()
        in_sync = (
            lease is not None
            and lease.holds
            and lease.gone_at is None
            and lease.start_at <= reservation.start_at
            and lease.end_at >= reservation.end_at
        )
        own.append({"reservation": reservation, "lease": lease, "in_sync": in_sync})
    return {
        "status": scheduler_link_status(now=now),
        "link": SchedulerLink.objects.filter(pk=1).first(),
        "own": own,
        "external": SchedulerLease.objects.filter(
            holds=True, gone_at__isnull=True, reservation__isnull=True, end_at__gt=now
        )
        .prefetch_related("resources")
        .order_by("start_at")[:200],
    }
