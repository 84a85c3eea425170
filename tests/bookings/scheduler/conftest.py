"""The stand-in broker as a separate process (``python -m bookings.scheduler.standin``).

One process per switch combination, started once for the session; every test starts from
an empty broker (``/_standin/reset``: no leases, no faults, the real clock).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
import requests

from bench.stack import Proc, free_port, python
from bookings.scheduler.config import SchedulerConfig
from bookings.scheduler.omf import OmfScheduler, wire_time

TOKEN = "standin-test-token"
LISTENING = re.compile(r"listening on http://127\.0\.0\.1:(\d+)")


@dataclass
class Standin:
    """A running stand-in and the adapter configuration that reaches it."""

    proc: Proc
    url: str
    config: SchedulerConfig
    args: tuple[str, ...] = field(default=())

    def control(self, path: str, body: dict[str, Any] | None = None) -> dict[str, Any]:
        response = requests.post(f"{self.url}/_standin/{path}", json=body or {}, timeout=10)
        assert response.status_code == 200, response.text
        answer: dict[str, Any] = response.json()
        return answer

    def reset(self) -> None:
        self.control("reset")

    def set_clock(self, now: datetime) -> None:
        self.control("clock", {"now": wire_time(now)})

    def faults(self, **switches: object) -> None:
        self.control("faults", switches)

    def seed(self, **lease: object) -> dict[str, Any]:
        return self.control("leases", lease)

    def scheduler(self, **changes: Any) -> OmfScheduler:
        return OmfScheduler(replace(self.config, **changes))

    def stop(self) -> int:
        return self.proc.stop()


def standin_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if not k.startswith("SCHEDULER_")}


def start_standin(*args: str, token: str | None = None, port: int = 0) -> Standin:
    argv = [python(), "-m", "bookings.scheduler.standin", "--host", "127.0.0.1"]
    argv += ["--port", str(port), "--test-control", "--threads", "8", *args]
    if token:
        argv += ["--token", token]
    proc = Proc("standin", argv, standin_env())
    try:
        line = proc.wait_for_line(lambda text: LISTENING.search(text) is not None, timeout_s=30)
    except BaseException:
        proc.stop()
        raise
    match = LISTENING.search(line)
    assert match is not None
    url = f"http://127.0.0.1:{match.group(1)}"
    config = SchedulerConfig(base_url=url, token=token, read_timeout_s=5.0)
    return Standin(proc=proc, url=url, config=config, args=tuple(args))


@pytest.fixture(scope="session")
def standin_401() -> Iterator[Standin]:
    """omf_sfa's manners: a clash is a 401, an empty list is [], a token is required."""
    standin = start_standin("--conflict-as", "401", token=TOKEN)
    yield standin
    standin.stop()


@pytest.fixture(scope="session")
def standin_409() -> Iterator[Standin]:
    """Another deployment's: a clash is a 409, an empty list is a 404, no authentication."""
    standin = start_standin("--conflict-as", "409", "--empty-as-404")
    yield standin
    standin.stop()


@pytest.fixture(scope="session")
def standin_zombie() -> Iterator[Standin]:
    """Older omf_sfa: a clash answers a pending lease with no components."""
    standin = start_standin("--conflict-as", "zombie")
    yield standin
    standin.stop()


@pytest.fixture(scope="session")
def standin_slots() -> Iterator[Standin]:
    """Leases on a 10-minute grid (R2lab's granularity)."""
    standin = start_standin("--granularity-s", "600")
    yield standin
    standin.stop()


@pytest.fixture(params=["401", "409"])
def standin(request: pytest.FixtureRequest) -> Standin:
    """The behaviours every deployment shares, once per way of reporting a clash."""
    chosen: Standin = request.getfixturevalue(f"standin_{request.param}")
    chosen.reset()
    return chosen


@pytest.fixture
def omf_sfa(standin_401: Standin) -> Standin:
    standin_401.reset()
    return standin_401


@pytest.fixture
def zombie(standin_zombie: Standin) -> Standin:
    standin_zombie.reset()
    return standin_zombie


@pytest.fixture
def slots(standin_slots: Standin) -> Standin:
    standin_slots.reset()
    return standin_slots


@pytest.fixture
def tomorrow() -> datetime:
    """A whole hour a day ahead, so that nothing here is in the broker's past."""
    now = datetime.now(UTC).replace(minute=0, second=0, microsecond=0)
    return now + timedelta(days=1)


def unused_url() -> str:
    return f"http://127.0.0.1:{free_port()}"
