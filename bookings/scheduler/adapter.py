"""What the booking code needs from the testbed's scheduler, whatever its dialect.

The 24 fixed nodes belong to the AMazING scheduler: the portal books them there, as one
*lease* per booking holding every fixed node the booking includes (all-or-nothing). A dialect
module (``omf.py`` for the omf_sfa broker) implements :class:`Scheduler`; the booking code
sees only this module's types. No Django here: the stand-in broker and the unit tests import
it as plain Python.

Every failure is a :class:`SchedulerError` whose ``retryable`` says whether trying again
later can help (the broker is down, slow or answers 5xx) or not (the request conflicts with
another lease, or the broker refused it).
"""

from __future__ import annotations

import enum
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Protocol

from bookings.periods import overlaps


class LeaseStatus(enum.StrEnum):
    """A lease's life: ``pending → accepted → active → past``, or ``cancelled``.

    Only ``accepted`` and ``active`` leases hold their nodes.
    """

    PENDING = "pending"
    ACCEPTED = "accepted"
    ACTIVE = "active"
    PAST = "past"
    CANCELLED = "cancelled"

    @property
    def holds_nodes(self) -> bool:
        return self in (LeaseStatus.ACCEPTED, LeaseStatus.ACTIVE)


# The leases that matter for a calendar: not yet over and not cancelled.
LIVE_STATUSES: tuple[LeaseStatus, ...] = (
    LeaseStatus.PENDING,
    LeaseStatus.ACCEPTED,
    LeaseStatus.ACTIVE,
)
ALL_STATUSES: tuple[LeaseStatus, ...] = tuple(LeaseStatus)


@dataclass(frozen=True)
class Node:
    """A resource the scheduler leases (a fixed node)."""

    uuid: str
    name: str
    urn: str
    available: bool = True
    exclusive: bool = True


@dataclass(frozen=True)
class Lease:
    """One lease as the broker answered it. Times are aware and in UTC, whole seconds."""

    uuid: str
    name: str
    valid_from: datetime
    valid_until: datetime
    status: LeaseStatus
    account_name: str
    component_names: tuple[str, ...]

    @property
    def holds_nodes(self) -> bool:
        return self.status.holds_nodes and bool(self.component_names)

    def overlaps(self, *, start: datetime | None, end: datetime | None) -> bool:
        """Half-open: a lease that ends exactly when the window starts does not overlap.

        ``None`` leaves the window open on that side.
        """
        return overlaps(self.valid_from, self.valid_until, start, end)


class SchedulerError(Exception):
    """The scheduler could not do what was asked.

    ``reason`` is the broker's own words when it gave any; ``status_code`` its HTTP status
    (``None`` when no answer came at all).
    """

    retryable: bool = False

    def __init__(self, message: str, *, reason: str = "", status_code: int | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.reason = reason
        self.status_code = status_code


class SchedulerUnavailable(SchedulerError):
    """No usable answer: connection refused, timeout, 5xx. Trying again later can help."""

    retryable = True


class SchedulerRejected(SchedulerError):
    """The broker refused the request (4xx) or answered something that is not its protocol."""


class SchedulerAuthFailed(SchedulerRejected):
    """The broker does not accept our credentials (token, client certificate, TLS trust)."""


class SchedulerNotFound(SchedulerRejected):
    """No such lease on the broker."""


class SchedulerConflict(SchedulerError):
    """Another lease holds some of the nodes in that window.

    ``node_names`` are the nodes the broker's answer let us identify (possibly none: some
    brokers only say that the reservation failed).
    """

    def __init__(
        self,
        message: str,
        *,
        node_names: Sequence[str] = (),
        reason: str = "",
        status_code: int | None = None,
    ) -> None:
        super().__init__(message, reason=reason, status_code=status_code)
        self.node_names: tuple[str, ...] = tuple(node_names)


class Scheduler(Protocol):
    """The testbed scheduler as the booking code uses it.

    Times passed in must be timezone-aware. A lease always covers what was asked: its start
    is floored and its end ceiled to the broker's granularity (whole seconds at least).
    """

    def list_nodes(self) -> list[Node]:
        """Every node the broker leases."""
        ...

    def list_leases(
        self,
        *,
        window_start: datetime | None = None,
        window_end: datetime | None = None,
        statuses: Collection[LeaseStatus] = LIVE_STATUSES,
    ) -> list[Lease]:
        """Leases in those statuses overlapping ``[window_start, window_end)``, by start.

        Leases that hold no component (a broker's debris) are left out.
        """
        ...

    def get_lease(self, *, uuid: str | None = None, name: str | None = None) -> Lease | None:
        """The lease with that uuid (or, failing a uuid, that name), in any status.

        Brokers do not keep names unique: by name, a live lease comes before ended ones.
        """
        ...

    def create_lease(
        self,
        *,
        name: str,
        valid_from: datetime,
        valid_until: datetime,
        component_names: Sequence[str],
        account_name: str | None = None,
    ) -> Lease:
        """One lease holding every named node, or none (raises :class:`SchedulerConflict`).

        ``account_name`` defaults to the configured account.
        """
        ...

    def move_lease(self, *, uuid: str, valid_from: datetime, valid_until: datetime) -> Lease:
        """New times for a lease; the broker checks them again against other leases."""
        ...

    def cancel_lease(self, *, uuid: str) -> Lease:
        """Cancel a lease; answers it, now ``cancelled`` (or ``past`` if it had ended)."""
        ...

    def close(self) -> None:
        """Release connections."""
        ...

    def __enter__(self) -> Scheduler: ...

    def __exit__(self, *exc_info: object) -> None: ...


_EPOCH_UTC = datetime(1970, 1, 1, tzinfo=UTC)


def covering_window(
    *, valid_from: datetime, valid_until: datetime, granularity_s: int = 1
) -> tuple[datetime, datetime]:
    """The smallest window on the broker's grid that covers ``[valid_from, valid_until)``.

    The lease must cover the booking, so the start is floored and the end ceiled (to whole
    seconds, or to the broker's slot granularity). Raises ``ValueError`` for naive times,
    an empty window or a granularity below one second.
    """
    for label, value in (("valid_from", valid_from), ("valid_until", valid_until)):
        if value.tzinfo is None or value.utcoffset() is None:
            raise ValueError(f"{label} must be timezone-aware, got {value!r}")
    if valid_from >= valid_until:
        raise ValueError(f"valid_from {valid_from} must be before valid_until {valid_until}")
    if granularity_s < 1:
        raise ValueError(f"granularity_s must be at least 1, got {granularity_s}")
    step = timedelta(seconds=granularity_s)
    start_slots = (valid_from - _EPOCH_UTC) // step
    end_slots = -((_EPOCH_UTC - valid_until) // step)
    return _EPOCH_UTC + start_slots * step, _EPOCH_UTC + end_slots * step
