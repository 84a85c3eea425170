"""The agent's write operations on runs, as the API calls them.

Each takes keyword-only arguments and raises domain exceptions (:mod:`basestation.errors`,
:class:`basestation.program.InvalidRunBody`); the API maps them to status codes.
"""

from __future__ import annotations

import logging
import re

from basestation.config import AgentConfig
from basestation.errors import RunConflict, RunNotFound, StorageFull
from basestation.manager import RunControl
from basestation.manual import ManualCommand, StopRequest
from basestation.program import InvalidRunBody, RunSpec, check_run_admissible, parse_run_body
from basestation.store import ABORTED, CANCELLED, RUNNING, STAGED, RunRecord, RunStore
from basestation.system import DiskSpace
from basestation.tick_rules import EstopLatch, ManualDrive

RUN_ID_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,64}")
# What one sample costs on disk: about 110 bytes in the table with its key, plus the WAL
# copy until the next checkpoint, rounded up generously.
BYTES_PER_SAMPLE = 256
MB = 1_000_000

logger = logging.getLogger(__name__)


def is_valid_run_id(run_id: str) -> bool:
    return RUN_ID_PATTERN.fullmatch(run_id) is not None


def run_stage(
    *,
    store: RunStore,
    manager: RunControl,
    config: AgentConfig,
    run_id: str,
    body: object,
    now_s: float,
    disk: DiskSpace | None = None,
) -> tuple[RunRecord, bool]:
    """Stage a run (idempotent by id); returns (record, created).

    ``disk`` is the free space of the run store's file system; a new run that would leave
    less than ``AGENT_MIN_FREE_DISK_MB`` once it and every other staged run have recorded
    raises :class:`StorageFull`.
    """
    if not is_valid_run_id(run_id):
        raise InvalidRunBody({"run_id": ["must be 1 to 64 characters from A-Z a-z 0-9 _ -"]})
    spec = parse_run_body(body)

    def admit(new_spec: RunSpec) -> None:
        check_run_admissible(new_spec, max_velocity_mps=config.max_velocity_mps, now_s=now_s)
        _check_disk_room(store=store, config=config, spec=new_spec, now_s=now_s, disk=disk)

    record, created = store.stage_run(run_id, spec, now_s=now_s, admit=admit)
    if created:
        manager.notify_runs_changed()
    return record, created


def run_withdraw(*, store: RunStore, manager: RunControl, run_id: str, now_s: float) -> RunRecord:
    """Cancel a staged run or abort a running one (the next ticks ramp the robot to zero)."""
    # Two rounds: the control loop may start the run between our read and our write.
    for _ in range(2):
        record = store.get_run(run_id) if is_valid_run_id(run_id) else None
        if record is None:
            raise RunNotFound(run_id)
        if record.state == STAGED:
            to_state, reason = CANCELLED, "cancelled through the API before its start"
        elif record.state == RUNNING:
            to_state, reason = ABORTED, "aborted through the API while running"
        else:
            raise RunConflict("already_ended", f"run {run_id} has already ended ({record.state})")
        if store.transition(
            run_id, from_states=[record.state], to_state=to_state, reason=reason, now_s=now_s
        ):
            manager.notify_runs_changed()
            updated = store.get_run(run_id)
            assert updated is not None
            return updated
    record = store.get_run(run_id)
    assert record is not None
    raise RunConflict("already_ended", f"run {run_id} has already ended ({record.state})")


def _check_disk_room(
    *, store: RunStore, config: AgentConfig, spec: RunSpec, now_s: float, disk: DiskSpace | None
) -> None:
    if config.min_free_disk_mb == 0 or disk is None:
        return
    # Planned on the window, not the program: the robot is recorded until it has stopped.
    ahead_s = store.active_seconds_ahead(now_s) + max(
        0.0, spec.end_at_s - max(spec.start_at_s, now_s)
    )
    needed_bytes = ahead_s * config.control_hz * BYTES_PER_SAMPLE
    reserve_bytes = config.min_free_disk_mb * MB
    if disk.free_bytes - needed_bytes < reserve_bytes:
        raise StorageFull(
            f"not enough disk for this run: {disk.free_bytes / MB:.0f} MB free, the staged "
            f"runs with this one need about {needed_bytes / MB:.0f} MB, and the agent keeps "
            f"{config.min_free_disk_mb:g} MB free (AGENT_MIN_FREE_DISK_MB). Free space on "
            "the base station or shorten AGENT_RETENTION_DAYS."
        )


def manual_drive(
    *, manager: RunControl, command: ManualCommand, now_s: float
) -> tuple[ManualDrive | None, str | None]:
    """Drive the robot by hand (admins); see :meth:`RunManager.drive_manually`."""
    return manager.drive_manually(
        now_s=now_s,
        user=command.user,
        velocity_mps=command.velocity_mps,
        direction=command.direction,
        ttl_s=command.ttl_s,
        force=command.force,
    )


def estop_latch(
    *, manager: RunControl, request: StopRequest, now_s: float
) -> tuple[EstopLatch, str | None]:
    reason = request.reason or "emergency stop through the API"
    if request.user:
        reason = f"{reason} (by {request.user})"
    return manager.latch_estop(now_s=now_s, reason=reason)


def estop_release(*, manager: RunControl, request: StopRequest, now_s: float) -> bool:
    if request.user:
        # The latch itself has no owner; the log says who let the robot go again.
        logger.warning("e-stop release requested by %s", request.user)
    return manager.release_estop(now_s=now_s)
