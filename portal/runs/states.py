"""A run's states and the one table of the changes allowed between them.

``run_transition`` (``portal/runs/services/transitions.py``) refuses any change that is not
in :data:`TRANSITIONS` for the cause that asks for it, the Django admin included. The README
shows the same table as a diagram; a test keeps the two in step.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Final

from django.db import models

from basestation.contract import PORTAL_STATE_FOR_AGENT_END


class RunState(models.TextChoices):
    SCHEDULED = "scheduled", "scheduled"
    STAGED = "staged", "staged on the base station"
    RUNNING = "running", "running"
    COLLECTING = "collecting", "collecting data"
    COMPLETED = "completed", "completed"
    CANCELLED = "cancelled", "cancelled"
    FAILED = "failed", "failed"
    INTERRUPTED = "interrupted", "interrupted (partial data kept)"


class Cause(models.TextChoices):
    """Who may cause a change of state."""

    # The owner or an admin booking, moving, cancelling; an admin rejecting a request.
    BOOKING = "booking", "booking"
    # The Celery workers staging runs on their agents and collecting their data.
    DISPATCH = "dispatch", "dispatch"
    # An admin's named action on a run (Django admin), with a reason.
    ADMIN = "admin", "admin action"


RUN_ACTIVE_STATES: Final = (RunState.STAGED, RunState.RUNNING, RunState.COLLECTING)
RUN_END_STATES: Final = (
    RunState.COMPLETED,
    RunState.CANCELLED,
    RunState.FAILED,
    RunState.INTERRUPTED,
)

S = RunState
# (from, to) → the causes that may make that change. "" is "no run yet".
TRANSITIONS: Final[Mapping[tuple[str, str], frozenset[Cause]]] = {
    ("", S.SCHEDULED): frozenset({Cause.BOOKING}),
    (S.SCHEDULED, S.STAGED): frozenset({Cause.DISPATCH}),
    (S.SCHEDULED, S.CANCELLED): frozenset({Cause.BOOKING}),
    # Not approved in time, base station unreachable until the end, or it refused the run.
    (S.SCHEDULED, S.FAILED): frozenset({Cause.DISPATCH, Cause.ADMIN}),
    (S.STAGED, S.RUNNING): frozenset({Cause.DISPATCH}),
    # Withdrawn from the base station before it started.
    (S.STAGED, S.CANCELLED): frozenset({Cause.DISPATCH}),
    # Ended on the base station: its data is being collected.
    (S.STAGED, S.COLLECTING): frozenset({Cause.DISPATCH}),
    (S.RUNNING, S.COLLECTING): frozenset({Cause.DISPATCH}),
    # The base station lost the run. An admin may give up only on a run the base station
    # no longer drives (collecting stuck on samples that will never come); a staged or
    # running one is stopped by cancelling its booking, which aborts it on the robot.
    (S.STAGED, S.FAILED): frozenset({Cause.DISPATCH}),
    (S.RUNNING, S.FAILED): frozenset({Cause.DISPATCH}),
    (S.COLLECTING, S.FAILED): frozenset({Cause.DISPATCH, Cause.ADMIN}),
    # Every sample collected: the end the base station reported (contract mapping).
    (S.COLLECTING, S.COMPLETED): frozenset({Cause.DISPATCH}),
    (S.COLLECTING, S.INTERRUPTED): frozenset({Cause.DISPATCH}),
    (S.COLLECTING, S.CANCELLED): frozenset({Cause.DISPATCH}),
}


def sources(to_state: str, cause: Cause) -> tuple[str, ...]:
    """The states from which ``cause`` may move a run to ``to_state``."""
    return tuple(
        from_state
        for (from_state, target), causes in TRANSITIONS.items()
        if target == to_state and cause in causes and from_state
    )


def allowed(from_state: str, to_state: str, cause: Cause) -> bool:
    return cause in TRANSITIONS.get((from_state, to_state), frozenset())


# How a run's end on its base station ends it here (``basestation/contract.py``).
STATE_FOR_AGENT_END: Final[Mapping[str, RunState]] = {
    agent: RunState(portal) for agent, portal in PORTAL_STATE_FOR_AGENT_END.items()
}
