"""Domain exceptions of the agent; the API maps each to one HTTP status in one place."""

from __future__ import annotations

from typing import Literal

ConflictKind = Literal["body_differs", "window_overlaps", "already_ended"]


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
