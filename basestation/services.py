"""The agent's write operations on runs, as the API calls them.

Each takes keyword-only arguments and raises domain exceptions (:mod:`basestation.errors`,
:class:`basestation.program.InvalidRunBody`); the API maps them to status codes.
"""

from __future__ import annotations

import re

from basestation.config import AgentConfig
from basestation.errors import RunConflict, RunNotFound
from basestation.manager import RunManager
from basestation.program import InvalidRunBody, RunSpec, check_run_admissible, parse_run_body
from basestation.store import ABORTED, CANCELLED, RUNNING, STAGED, RunRecord, RunStore

RUN_ID_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,64}")


def is_valid_run_id(run_id: str) -> bool:
    return RUN_ID_PATTERN.fullmatch(run_id) is not None


def run_stage(
    *,
    store: RunStore,
    manager: RunManager,
    config: AgentConfig,
    run_id: str,
    body: object,
    now_s: float,
) -> tuple[RunRecord, bool]:
    """Stage a run (idempotent by id); returns (record, created)."""
    if not is_valid_run_id(run_id):
        raise InvalidRunBody({"run_id": ["must be 1 to 64 characters from A-Z a-z 0-9 _ -"]})
    spec = parse_run_body(body)

    def admit(new_spec: RunSpec) -> None:
        check_run_admissible(new_spec, max_velocity_mps=config.max_velocity_mps, now_s=now_s)

    record, created = store.stage_run(run_id, spec, now_s=now_s, admit=admit)
    if created:
        manager.notify_runs_changed()
    return record, created


def run_withdraw(*, store: RunStore, manager: RunManager, run_id: str, now_s: float) -> RunRecord:
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
