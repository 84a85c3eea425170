"""What the soak records (faults, bookings, runs, its result) and the names of its checks."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from typing import Any

from bench.stack import REPO

DEFAULT_MINUTES = 30.0
CHAOS_EVERY_S = (60.0, 180.0)
PROGRAM_S = 30.0
# A reservation lasts its program and this much more (the run's collection ends inside it).
SLACK_S = 4.0
# From a booking to its start: staged by the next sweeps.
LEAD_S = 8.0
FIXED_NODE_SHARE = 1 / 3
VELOCITY_MPS = 0.5
# A booking that gets no answer is retried with its key for this long at most.
RETRY_FOR_S = 180.0
# A hold counts as explained by a fault on the robot's agent this long before it.
HOLD_EXPLAINED_WITHIN_S = 300.0
DATABASE = "amazing_soak"
REPORT = REPO / "docs" / "reliability.md"
PLOT = REPO / "docs" / "reliability-soak.png"

# Robot, its agent's process, and the fixed nodes its bookings may hold (the two robots'
# nodes apart: a refusal for a node the other robot's booking holds would only be noise).
ROBOTS = {
    "mobile-1": ("agent", ("node-01", "node-03", "node-05")),
    "mobile-2": ("agent-2", ("node-02", "node-04", "node-06")),
}
# Fault kinds: the process killed (by its name in ``portal.processes``), in words.
KILLED = {
    "worker": "runs worker",
    "mail": "mail worker",
    "beat": "beat",
    "redis": "Redis",
    "agent": "agent",
    "web": "web server",
    "scheduler": "stand-in scheduler",
}
POSTGRES_RESTART = "postgresql"
# Each Celery queue and the worker process that takes its tasks (portal.processes).
QUEUE_WORKERS = {"runs": "worker", "mail": "mail"}
FAULT_NAMES = {**KILLED, POSTGRES_RESTART: "PostgreSQL restart"}
END_STATES = ("completed", "interrupted", "failed", "cancelled")
CHECKS = {
    "runs_ended": "every run in an end state",
    "samples_exact": "each run holds exactly its agent's samples",
    "missing_equals_gaps": "each interrupted run's missing ranges equal the agent's gaps",
    "no_duplicates": "no sample stored twice",
    "keys_once": "no idempotency key booked twice",
    "leases_match": "no lease without its booking, no booking without its lease",
    "no_task_stuck": "no task left in the broker",
    "holds_explained": "every robot hold lifted or explained",
}


def say(line: str) -> None:
    print(f"soak {datetime.now(UTC):%H:%M:%S} {line}", flush=True)


@dataclass
class Fault:
    kind: str
    at_s: float  # since the soak's start
    target: str  # the process killed (which agent), or the server restarted


@dataclass
class Booking:
    robot: str
    key: str
    start_at: str
    end_at: str
    nodes: list[str]
    attempts: int = 0
    errors: list[str] = field(default_factory=list)
    reservation_id: int | None = None
    run_id: int | None = None
    refused: str = ""


@dataclass
class RunRecord:
    id: int
    robot: str
    nodes: list[str]
    start_s: float
    end_s: float
    state: str
    samples: int
    agent_samples: int
    reason: str


@dataclass
class SoakResult:
    minutes: float
    seed: int
    started_at: str
    machine: str
    faults: list[Fault]
    restarts: list[tuple[str, float]]
    bookings: list[Booking]
    runs: list[RunRecord]
    holds: list[dict[str, Any]]
    misses: dict[str, list[str]]
    samples_stored: int = 0
    samples_on_agents: int = 0
    leases: int = 0
    # Leases on the scheduler holding nodes for no booking; bookings whose lease does not.
    orphan_leases: int = 0
    bookings_without_lease: int = 0
    # Tasks a killed worker had taken: Redis hands them out again after its visibility timeout.
    awaiting_redelivery: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not any(self.misses.values())

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["ok"] = self.ok
        return data
