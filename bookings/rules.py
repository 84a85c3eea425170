"""May this be booked, moved or cancelled, and if not, why: the one answer for every way of
booking.

Every refusal is a :class:`Problem` with a code (:data:`PROBLEM_CODES`); a service raises the
first one (``Problem.as_error``), the calendar's live check shows them all.

- :func:`request_problems`: the request itself, before any time is looked at — the resources
  chosen (at least one, none twice), who may book for someone else, who may override quotas,
  whose program it is.
- :func:`booking_problems`: holding some resources for a period — the time window, resources
  out of service, the program that a mobile node would run, maintenance windows, other
  bookings, leases on the testbed scheduler, quota policies — in that order.
  ``reservation_create`` and ``reservation_reschedule`` call it under their locks; the live
  check calls it without a lock. Both therefore say the same thing about the same booking.
- :func:`needs_approval`: whether a booking waits for an admin.
- :func:`move_problems`, :func:`cancel_problems`, :func:`decision_problems`: changing a
  booking. What only the runs layer knows (its run has left the schedule) comes in as an
  argument: bookings know nothing of runs.

:func:`velocity_limit` is the portal's one answer to "how fast may this robot go": the
stricter of the resource's own limit and the one its base-station agent reports (the layers'
limits nest: firmware ≥ agent ≥ portal, each layer only stricter; docs/architecture.md
"Velocity limits"), naming which of the two limits.
:func:`velocity_problem` checks a velocity against it: programs at booking (the booked robot),
programs when written (:func:`robots_fitting`, every robot the author may book) and manual
drive. :func:`resource_limit_problem` refuses a resource limit looser than its agent's.

One thing: the booking rules, the one answer to "may this be booked, moved or cancelled"; the
services, the live check and the lease API all ask here, so the rules are read in one file.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Final, Literal, Protocol, get_args

from django.conf import settings
from django.utils import timezone

from bookings import queries
from bookings.choices import (
    RESERVATION_ACTIVE_STATES,
    BookedVia,
    ReservationState,
    ResourceKind,
)
from bookings.leases import public_id_of
from bookings.models import (
    Blackout,
    Reservation,
    ReservationItem,
    Resource,
    SchedulerLease,
)
from bookings.quotas import quota_violations
from bookings.scheduler import Lease
from core.accounts.models import User
from core.errors import Conflict, DomainError, InvalidInput, NotAllowed


class QuotaExceeded(Conflict):
    code = "quota_exceeded"


class ProgramRefused(InvalidInput):
    """The program a mobile node would run does not fit it or the booking (a 400 as any bad
    input; a door that books around an existing program, the lease API, answers it as a
    conflict with that program)."""


# Segments are numbered from 0 wherever they are shown or written: the program's list, the
# robot's samples, the CSV, JSON and Parquet files, the analysis, the pages and the messages.
FIRST_SEGMENT: Final = 0

LimitSource = Literal["portal", "agent"]

ProblemCode = Literal[
    # the request: resources chosen (400), who may do this (403)
    "resources",
    "permission",
    # the booking, in the order booking_problems finds them
    "window",
    "out_of_service",
    "program",
    "blackout",
    "booked",
    "lease",
    "quota",
    # changing a booking: its state (409), a reason it needs (400)
    "state",
    "reason",
]
PROBLEM_CODES: Final[tuple[ProblemCode, ...]] = get_args(ProblemCode)


class Program(Protocol):
    """What booking needs to know of the program a mobile node will run."""

    @property
    def duration_s(self) -> float: ...

    @property
    def velocities_mps(self) -> Sequence[float]: ...


@dataclass(frozen=True)
class Problem:
    """One reason a booking cannot be made or changed. ``overridable``: an admin may book past
    it. ``field`` is the input it is about; empty when it is about the whole request."""

    code: ProblemCode
    field: str
    message: str
    overridable: bool = False
    # Every message of a kind that comes as a list (the quota rules a booking breaks).
    messages: tuple[str, ...] = ()

    def as_error(self) -> DomainError:
        if self.code == "quota":
            return QuotaExceeded(self.message, fields={"quota": list(self.messages)})
        kind: type[DomainError] = InvalidInput
        if self.code == "program":
            kind = ProgramRefused
        elif self.code == "permission":
            kind = NotAllowed
        elif self.code in ("blackout", "booked", "lease", "state"):
            kind = Conflict
        return kind.on_field(self.field, self.message) if self.field else kind(self.message)

    def as_json(self) -> dict[str, object]:
        return {"code": self.code, "field": self.field, "message": self.message}


def aware_utc(value: datetime, field_name: str) -> datetime:
    """The instant in UTC: lengths computed from it are real elapsed time, DST or not."""
    if timezone.is_naive(value):
        raise InvalidInput.on_field(
            field_name, "Give a time zone (for example 2026-05-01T10:00+01:00)."
        )
    return value.astimezone(UTC)


@dataclass(frozen=True)
class VelocityLimit:
    """How fast a mobile node may go, and which layer says so."""

    resource: str
    mps: float
    source: LimitSource

    def describe(self) -> str:
        if self.source == "agent":
            return f"{self.mps:g} m/s, the limit its base station reports"
        return f"{self.mps:g} m/s, the portal's limit for it"


def velocity_limit(resource: Resource) -> VelocityLimit | None:
    """The stricter of the resource's limit and its agent's (None: not a mobile node).

    The agent's is the one recorded by the health sweep from its ``GET /status``; until an
    agent has reported, the resource's own limit stands alone.
    """
    portal = resource.max_velocity_mps
    if portal is None:
        return None
    agent = resource.agent_max_velocity_mps
    if agent is not None and agent < portal:
        return VelocityLimit(resource.name, agent, "agent")
    return VelocityLimit(resource.name, portal, "portal")


def may_book_for_others(by: User) -> bool:
    """Admins, and the accounts that book through the scheduler's vocabulary for others."""
    return by.is_testbed_admin or by.has_perm("bookings.lease_inbound")


def needs_approval(*, resources: Sequence[Resource], by: User) -> bool:
    """A booking of a resource that requires approval waits for an admin, unless one makes it."""
    return any(r.requires_approval for r in resources) and not by.is_testbed_admin


def request_problems(
    *,
    owner: User,
    by: User,
    resources: Sequence[Resource],
    override_reason: str = "",
    program_owner_id: int | None = None,
) -> list[Problem]:
    """What is wrong with ``by`` asking to book ``resources`` for ``owner``, at any time.

    ``override_reason``: the admin's reason to book past quotas. ``program_owner_id``: who
    wrote the program a mobile node would run, when there is one (only its owner books it).
    """
    problems = []
    if not resources:
        problems.append(Problem("resources", "resources", "Choose at least one resource."))
    elif len({r.pk for r in resources}) != len(resources):
        problems.append(Problem("resources", "resources", "A resource is listed twice."))
    if by.pk != owner.pk and not may_book_for_others(by):
        problems.append(Problem("permission", "", "Only admins book for someone else."))
    if override_reason.strip() and not by.is_testbed_admin:
        problems.append(
            Problem("permission", "override_reason", "Only admins can override quotas.")
        )
    if program_owner_id is not None and program_owner_id != owner.pk:
        problems.append(
            Problem("permission", "experiment", "That experiment belongs to someone else.")
        )
    return problems


def move_problems(
    *, reservation: Reservation, by: User, now: datetime, run_started: bool = False
) -> list[Problem]:
    """Why ``by`` may not move ``reservation`` now. ``run_started``: its run has left the
    schedule (staged on its base station, or further), which only the runs layer knows."""
    if reservation.owner_id != by.pk and not may_book_for_others(by):
        return [
            Problem("permission", "", "Only the owner or an admin can change this reservation.")
        ]
    if run_started:
        return [
            Problem("state", "", "Its run is already on the base station; cancel and book again.")
        ]
    if reservation.state not in RESERVATION_ACTIVE_STATES or reservation.start_at <= now:
        return [Problem("state", "", "Only upcoming reservations can be moved.")]
    return []


def cancel_problems(*, reservation: Reservation, by: User, reason: str) -> list[Problem]:
    """Why ``by`` may not cancel ``reservation`` (an admin cancelling another's says why)."""
    if reservation.owner_id != by.pk and not may_book_for_others(by):
        return [
            Problem("permission", "", "Only the owner or an admin can cancel this reservation.")
        ]
    problems = []
    if reservation.state not in RESERVATION_ACTIVE_STATES:
        problems.append(
            Problem("state", "", f"The reservation is already {reservation.get_state_display()}.")
        )
    if by.pk != reservation.owner_id and not reason.strip():
        problems.append(
            Problem("reason", "reason", "Say why you cancel someone else's reservation.")
        )
    return problems


def attach_problems(
    *,
    reservation: Reservation,
    by: User,
    now: datetime,
    has_program: bool,
    program_owner_id: int,
) -> list[Problem]:
    """Why ``by`` may not give ``reservation`` a program now.

    A booking made through the lease API holds its robot without a program; its owner may
    attach one of their experiments before it starts. ``has_program``: it already has one
    (which only the runs layer knows). The booking rules then apply as to a new booking.
    """
    if reservation.owner_id != by.pk:
        return [
            Problem("permission", "", "Only the booking's owner can attach an experiment to it.")
        ]
    if program_owner_id != reservation.owner_id:
        return [Problem("permission", "experiment", "That experiment belongs to someone else.")]
    if reservation.booked_via != BookedVia.SCHEDULER:
        return [
            Problem(
                "state",
                "",
                "Only a booking made through the lease API waits for an experiment; book "
                "this one's experiment with it.",
            )
        ]
    if has_program:
        return [Problem("state", "", "This booking already has its experiment.")]
    if reservation.state not in RESERVATION_ACTIVE_STATES or reservation.start_at <= now:
        return [
            Problem("state", "", "An experiment can be attached only before the booking starts.")
        ]
    return []


def decision_problems(
    *, reservation: Reservation, by: User, approve: bool, reason: str
) -> list[Problem]:
    """Why ``by`` may not approve (or reject, saying why) ``reservation``."""
    if not by.is_testbed_admin:
        return [Problem("permission", "", "Only admins decide on reservations.")]
    problems = []
    if not approve and not reason.strip():
        problems.append(Problem("reason", "reason", "Say why the request is rejected."))
    if reservation.state != ReservationState.REQUESTED:
        problems.append(
            Problem(
                "state",
                "",
                f"The reservation is {reservation.get_state_display()}, not awaiting approval.",
            )
        )
    return problems


def velocity_problem(*, resource: Resource, velocity_mps: float) -> str | None:
    """Why ``velocity_mps`` is not allowed on ``resource``; None when it is."""
    limit = velocity_limit(resource)
    if limit is None:
        return f"{resource.name} is not a mobile node: it does not move."
    if velocity_mps < 0:
        return f"velocity {velocity_mps:g} m/s is negative (the direction says which way)."
    if velocity_mps > limit.mps:
        return (
            f"velocity {velocity_mps:g} m/s exceeds the maximum of {resource.name}: "
            f"{limit.describe()}."
        )
    return None


@dataclass(frozen=True)
class Fit:
    """Whether a program fits one robot: its fastest segment within the robot's limit."""

    limit: VelocityLimit
    fastest_mps: float

    @property
    def fits(self) -> bool:
        return self.fastest_mps <= self.limit.mps


def robots_fitting(robots: Sequence[Resource], velocities_mps: Sequence[float]) -> list[Fit]:
    """For each mobile node of ``robots`` (by name), whether a program with these velocities
    fits its limit: what an author learns when writing a program, before booking a robot."""
    fastest_mps = max(velocities_mps, default=0.0)
    fits = []
    for robot in sorted(robots, key=lambda r: r.name):
        limit = velocity_limit(robot)
        if limit is not None:
            fits.append(Fit(limit, fastest_mps))
    return fits


def resource_limit_problem(resource: Resource) -> str | None:
    """Why the resource's velocity limit cannot be saved: looser than its agent's (a program
    the portal accepted would be refused by the base station). None when it can."""
    portal, agent = resource.max_velocity_mps, resource.agent_max_velocity_mps
    if portal is None or agent is None or portal <= agent:
        return None
    return (
        f"{portal:g} m/s is above the {agent:g} m/s that {resource.name}'s base station "
        f"allows (AGENT_MAX_VELOCITY_MPS): set at most {agent:g} m/s, or raise the base "
        "station's limit first."
    )


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
    for index, velocity_mps in enumerate(program.velocities_mps, start=FIRST_SEGMENT):
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

    Found in one round trip of hand-written SQL (``queries.conflicts``: this runs under the
    booking lock on every booking); what it finds is read again through the ORM, only to
    word the refusal.
    """
    found = queries.conflicts(
        [r.pk for r in resources],
        start_at,
        end_at,
        exclude_reservation_id=exclude_reservation_id,
        first_only=first_only,
    )
    if not found:
        return []
    blackouts = Blackout.objects.in_bulk([pk for kind, pk in found if kind == "blackout"])
    items = ReservationItem.objects.select_related("resource").in_bulk(
        [pk for kind, pk in found if kind == "booked"]
    )
    problems = []
    for kind, pk in found:
        if kind == "blackout":
            window = blackouts[pk]
            since, until = _period(window.start_at), _period(window.end_at)
            problems.append(
                Problem(
                    "blackout",
                    "start_at",
                    f"Maintenance “{window.reason}” from {since} to {until}: nothing can be "
                    "booked then.",
                )
            )
        else:
            item = items[pk]
            since, until = _period(item.start_at), _period(item.end_at)
            message = f"{item.resource.name} is already booked from {since} to {until}."
            problems.append(Problem("booked", "start_at", message))
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
        # A lease made for a portal booking that still holds it is that booking's items,
        # found as "booked" already (as in the mirror: ``reservation`` is set on its row).
        booked = set(
            Reservation.objects.filter(
                public_id__in=[p for lease in fresh if (p := public_id_of(lease.name))],
                state__in=RESERVATION_ACTIVE_STATES,
            ).values_list("public_id", flat=True)
        )
        for lease in sorted(fresh, key=lambda x: x.valid_from):
            held = sorted(wanted.intersection(lease.component_names))
            if (
                lease.holds_nodes
                and held
                and lease.uuid != exclude_lease_uuid
                and public_id_of(lease.name) not in booked
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
