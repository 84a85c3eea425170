"""The testbed's scheduler (fixed-node leases): one interface, one module per dialect.

Nothing here imports Django. ``build_scheduler(config)`` answers the dialect's
implementation of :class:`Scheduler`; ``config.from_env`` reads the ``SCHEDULER_*``
settings. ``standin`` is a broker speaking the omf_sfa dialect, for ``make run`` and tests
(it needs Flask and waitress, so it is not imported here).
"""

from __future__ import annotations

from bookings.scheduler.adapter import (
    ALL_STATUSES,
    LIVE_STATUSES,
    Lease,
    LeaseStatus,
    Node,
    Scheduler,
    SchedulerAuthFailed,
    SchedulerConflict,
    SchedulerError,
    SchedulerNotFound,
    SchedulerRejected,
    SchedulerUnavailable,
    covering_window,
)
from bookings.scheduler.config import SchedulerConfig, from_env
from bookings.scheduler.omf import OmfScheduler

__all__ = [
    "ALL_STATUSES",
    "LIVE_STATUSES",
    "Lease",
    "LeaseStatus",
    "Node",
    "Scheduler",
    "SchedulerAuthFailed",
    "SchedulerConfig",
    "SchedulerConflict",
    "SchedulerError",
    "SchedulerNotFound",
    "SchedulerRejected",
    "SchedulerUnavailable",
    "build_scheduler",
    "covering_window",
    "from_env",
]


def build_scheduler(config: SchedulerConfig) -> Scheduler:
    """The implementation of the configured dialect (``SCHEDULER_DIALECT``)."""
    if config.dialect == "omf":
        return OmfScheduler(config)
    raise ValueError(f"no scheduler dialect {config.dialect!r}")
