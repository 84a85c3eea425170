"""Domain exceptions of the agent; the API maps each to one HTTP status in one place."""

from __future__ import annotations

from typing import Literal

ConflictKind = Literal[
    "body_differs",  # PUT: the id is staged with another body
    "window_overlaps",  # PUT: the window overlaps a staged or running run
    "already_ended",  # DELETE: the run has ended
    "robot_busy",  # POST /control: a run holds the robot (and no force)
    "estop_latched",  # POST /control: the emergency stop is latched
]


class RunNotFound(Exception):
    def __init__(self, run_id: str) -> None:
        super().__init__(f"no run {run_id!r} on this agent")
        self.run_id = run_id


class RunConflict(Exception):
    """The request contradicts the stored runs; ``kind`` says how (the API passes it on)."""

    def __init__(self, kind: ConflictKind, detail: str) -> None:
        super().__init__(detail)
        self.kind: ConflictKind = kind
        self.detail = detail


class StorageFull(Exception):
    """Staging the run would fill the disk of the run store (beyond AGENT_MIN_FREE_DISK_MB)."""

    def __init__(self, detail: str) -> None:
        super().__init__(detail)
        self.detail = detail
