"""Can this booking be made, and if not, why: the one answer for every way of booking.

:func:`booking_problems` lists what stands in the way of holding some resources for a
period — the time window, resources out of service, the program that a mobile node would run,
maintenance windows, other bookings, quota policies — in that order, each as a
:class:`Problem`. ``reservation_create`` and ``reservation_reschedule`` call it under their
locks and raise the first problem; the calendar's live check calls it without a lock and
shows them all. Both therefore say the same thing about the same booking.

:func:`velocity_problem` is the portal's one check of a velocity against a mobile node's
limit: programs (at booking and, against the fastest robot, when written) and manual drive.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Literal, Protocol

from django.conf import settings
from django.db.models import F, Q, Value
from django.utils import timezone

from bookings.choices import ResourceKind
from bookings.models import Blackout, ReservationItem, Resource, SchedulerLease
from bookings.quotas import quota_violations
from bookings.scheduler import Lease
from portal.accounts.models import User
from portal.errors import Conflict, DomainError, InvalidInput


class QuotaExceeded(Conflict):
    code = "quota_exceeded"


ProblemCode = Literal["window", "out_of_service", "program", "blackout", "booked", "lease", "quota"]


class Program(Protocol):
    """What booking needs to know of the program a mobile node will run."""

    @property
    def duration_s(self) -> float: ...

    @property
    def velocities_mps(self) -> Sequence[float]: ...


@dataclass(frozen=True)
class Problem:
    """One reason a booking cannot be made. ``overridable``: an admin may book past it."""

    code: ProblemCode
    field: str
    message: str
    overridable: bool = False
    # Every message of a kind that comes as a list (the quota rules a booking breaks).
    messages: tuple[str, ...] = ()

    def as_error(self) -> DomainError:
        if self.code == "quota":
            return QuotaExceeded(self.message, fields={"quota": list(self.messages)})
        if self.code in ("blackout", "booked", "lease"):
            return Conflict.on_field(self.field, self.message)
        return InvalidInput.on_field(self.field, self.message)

    def as_json(self) -> dict[str, object]:
        return {"code": self.code, "field": self.field, "message": self.message}


def aware_utc(value: datetime, field_name: str) -> datetime:
    """The instant in UTC: lengths computed from it are real elapsed time, DST or not."""
    if timezone.is_naive(value):
        raise InvalidInput.on_field(
            field_name, "Give a time zone (for example 2026-05-01T10:00+01:00)."
        )
    return value.astimezone(UTC)


def velocity_problem(*, resource: Resource, velocity_mps: float) -> str | None:
    """Why ``velocity_mps`` is not allowed on ``resource``; None when it is."""
    limit = resource.max_velocity_mps
    if limit is None:
        return f"{resource.name} is not a mobile node: it does not move."
    if velocity_mps < 0:
        return f"velocity {velocity_mps:g} m/s is negative (the direction says which way)."
    if velocity_mps > limit:
        return (
            f"velocity {velocity_mps:g} m/s exceeds the maximum {limit:g} m/s of {resource.name}."
        )
    return None


def _window_problems(start_at: datetime, end_at: datetime, now: datetime) -> list[Problem]:
    if end_at <= start_at:
        return [Problem("window", "end_at", "The end must be after the start.")]
    problems = []
    if start_at < now:
        problems.append(Problem("window", "start_at", "The start is in the past."))
    max_length = timedelta(seconds=settings.RESERVATION_MAX_S)
    if end_at - start_at > max_length:
        problems.append(
            Problem(
                "window",
                "end_at",
                f"A reservation lasts at most {max_length.total_seconds() / 3600:g} h.",
            )
        )
    return problems


def _program_problems(
    resources: Sequence[Resource], program: Program | None, length_s: float, *, required: bool
) -> list[Problem]:
    mobiles = [r for r in resources if r.kind == ResourceKind.MOBILE]
    if len(mobiles) > 1:
        return [Problem("program", "resources", "Book one mobile node per reservation.")]
    if not mobiles:
        if program is not None:
            return [Problem("program", "experiment", "Only mobile nodes run experiments.")]
        return []
    mobile = mobiles[0]
    if program is None:
        if not required:
            return []  # the robot is held, and stands still (a lease from the scheduler)
        return [Problem("program", "experiment", "Choose the experiment the robot will run.")]
    problems = []
    for index, velocity_mps in enumerate(program.velocities_mps, start=1):
        why = velocity_problem(resource=mobile, velocity_mps=velocity_mps)
        if why is not None:
            problems.append(Problem("program", "experiment", f"Segment {index}: {why}"))
    if program.duration_s > length_s:
        problems.append(
            Problem(
                "program",
                "end_at",
                f"The experiment lasts {program.duration_s:g} s but the reservation only "
                f"{length_s:g} s.",
            )
        )
    return problems


def _period(value: datetime) -> str:
    return f"{timezone.localtime(value):%Y-%m-%d %H:%M}"


def _conflicts(
    resources: Sequence[Resource],
    start_at: datetime,
    end_at: datetime,
    exclude_reservation_id: int | None,
    *,
    first_only: bool,
) -> list[Problem]:
    """Maintenance windows, then other bookings, that share time with the period.

    One round trip (a UNION): this runs under the booking lock on every booking.
    """
    ids = [r.pk for r in resources]
    blackout_ids = Blackout.resources.through.objects.filter(resource_id__in=ids).values(
        "blackout_id"
    )
    blackouts = (
        Blackout.objects.overlapping(start_at, end_at)
        .filter(Q(all_resources=True) | Q(pk__in=blackout_ids))
        .annotate(kind=Value("blackout"), label=F("reason"))
        .values("kind", "label", "start_at", "end_at")
        .order_by()  # SQLite allows no ORDER BY inside a compound statement's parts
    )
    items = ReservationItem.objects.overlapping(start_at, end_at).filter(
        resource_id__in=ids, active=True
    )
    if exclude_reservation_id is not None:
        items = items.exclude(reservation_id=exclude_reservation_id)
    booked = (
        items.annotate(kind=Value("booked"), label=F("resource__name"))
        .values("kind", "label", "start_at", "end_at")
        .order_by()
    )
    # "blackout" sorts before "booked": a maintenance window is the better explanation.
    rows = blackouts.union(booked, all=True).order_by("kind", "start_at")
    problems = []
    for row in rows[:1] if first_only else rows:
        since, until = _period(row["start_at"]), _period(row["end_at"])
        if row["kind"] == "blackout":
            message = (
                f"Maintenance “{row['label']}” from {since} to {until}: nothing can be booked then."
            )
        else:
            message = f"{row['label']} is already booked from {since} to {until}."
        problems.append(Problem(row["kind"], "start_at", message))
    return problems


def _lease_problem(
    nodes: Sequence[str], account: str, start_at: datetime, end_at: datetime, name: str
) -> Problem:
    by = f" by {account}" if account else ""
    return Problem(
        "lease",
        "start_at",
        f"{', '.join(sorted(nodes))} is leased on the testbed scheduler{by} from "
        f"{_period(start_at)} to {_period(end_at)} (lease “{name}”).",
    )


def _lease_problems(
    resources: Sequence[Resource],
    start_at: datetime,
    end_at: datetime,
    *,
    first_only: bool,
    fresh: Sequence[Lease] | None,
    exclude_lease_uuid: str,
) -> list[Problem]:
    """Leases on the testbed's scheduler holding one of ``resources`` (scheduler-owned).

    ``fresh`` is what the scheduler listed a moment ago (booking asks it first); without it
    the mirror speaks, where leases made for portal bookings are those bookings' items.
    """
    wanted = {r.name for r in resources}
    problems = []
    if fresh is not None:
        for lease in sorted(fresh, key=lambda x: x.valid_from):
            held = sorted(wanted.intersection(lease.component_names))
            if (
                lease.holds_nodes
                and held
                and lease.uuid != exclude_lease_uuid
                and lease.overlaps(start=start_at, end=end_at)
            ):
                problems.append(
                    _lease_problem(
                        held,
                        lease.account_name,
                        lease.valid_from,
                        lease.valid_until,
                        lease.name,
                    )
                )
        return problems[:1] if first_only else problems
    leases = (
        SchedulerLease.objects.overlapping(start_at, end_at)
        .filter(
            holds=True,
            gone_at__isnull=True,
            reservation__isnull=True,
            resources__in=[r.pk for r in resources],
        )
        .prefetch_related("resources")
        .distinct()
        .order_by("start_at")
    )
    for row in leases[:1] if first_only else leases:
        names = [r.name for r in row.resources.all() if r.name in wanted]
        problems.append(_lease_problem(names, row.account_name, row.start_at, row.end_at, row.name))
    return problems


def booking_problems(
    *,
    owner: User,
    resources: Sequence[Resource],
    start_at: datetime,
    end_at: datetime,
    program: Program | None,
    now: datetime,
    exclude_reservation_id: int | None = None,
    first_only: bool = False,
    program_required: bool = True,
    scheduler_owned: Sequence[Resource] = (),
    scheduler_leases: Sequence[Lease] | None = None,
    own_lease_uuid: str = "",
) -> list[Problem]:
    """Everything that forbids ``owner`` booking ``resources`` for ``[start_at, end_at)``.

    In the order a person fixes them: the window, resources out of service, the program,
    maintenance, other bookings, leases on the testbed scheduler (of the ``scheduler_owned``
    resources: as ``scheduler_leases`` listed them a moment ago, else from the mirror;
    ``own_lease_uuid`` is the booking's own), quotas (one :class:`Problem` listing every quota rule
    broken; an admin may override it). ``program_required=False`` lets a mobile node be held
    without a program (a lease asked for through the scheduler's vocabulary). ``first_only``
    stops at the first problem found, for the booking path that raises it. The resources'
    ``enabled`` and ``hold_reason`` (the health check's hold) are read from the instances
    given: under the booking lock they are the rows just locked.
    """
    problems = _window_problems(start_at, end_at, now)
    if problems and first_only:
        return problems[:1]
    if end_at <= start_at:
        return problems  # nothing else can be judged on an empty period
    problems += [
        Problem(
            "out_of_service",
            "resources",
            f"{r.name} is out of service: {r.hold_reason}."
            if r.hold_reason
            else f"{r.name} is out of service.",
        )
        for r in sorted(resources, key=lambda r: r.name)
        if not r.in_service
    ]
    problems += _program_problems(
        resources, program, (end_at - start_at).total_seconds(), required=program_required
    )
    if problems and first_only:
        return problems[:1]
    problems += _conflicts(
        resources, start_at, end_at, exclude_reservation_id, first_only=first_only
    )
    if problems and first_only:
        return problems[:1]
    if scheduler_owned:
        problems += _lease_problems(
            scheduler_owned,
            start_at,
            end_at,
            first_only=first_only,
            fresh=scheduler_leases,
            exclude_lease_uuid=own_lease_uuid,
        )
        if problems and first_only:
            return problems[:1]
    quota = quota_violations(
        user=owner,
        resources=resources,
        start_at=start_at,
        end_at=end_at,
        now=now,
        exclude_id=exclude_reservation_id,
    )
    if quota:
        problems.append(
            Problem("quota", "quota", quota[0], overridable=True, messages=tuple(quota))
        )
    return problems
