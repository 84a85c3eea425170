"""Fixtures for the base-station agent: an app with no control thread, driven by a fake clock."""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from flask import Flask
from flask.testing import FlaskClient

from basestation.app import create_app
from basestation.config import AgentConfig
from basestation.robot import Command, SimpleSimulatedRobot, Telemetry
from basestation.runtime import AgentRuntime, get_runtime

TOKEN = "test-token-0123456789abcdef"
PERIOD_S = 0.05  # the default 20 Hz


def iso(epoch_s: float) -> str:
    return datetime.fromtimestamp(epoch_s, tz=UTC).isoformat()


def run_body(
    start_s: float,
    *,
    window_s: float = 10.0,
    segments: list[dict[str, Any]] | None = None,
    owner: str = "alice",
    title: str = "two-way sweep",
    max_velocity_mps: float = 1.0,
    max_accel_mps2: float = 1.0,
) -> dict[str, Any]:
    """A valid body starting at ``start_s`` (epoch): 0.5 m/s cw 3 s, then 0.8 m/s ccw 3 s."""
    if segments is None:
        segments = [
            {"velocity_mps": 0.5, "direction": "cw", "duration_s": 3.0},
            {"velocity_mps": 0.8, "direction": "ccw", "duration_s": 3.0},
        ]
    return {
        "owner": owner,
        "title": title,
        "start_at": iso(start_s),
        "end_at": iso(start_s + window_s),
        "segments": copy.deepcopy(segments),
        "limits": {"max_velocity_mps": max_velocity_mps, "max_accel_mps2": max_accel_mps2},
    }


@dataclass
class RecordingRobot:
    """The simulated robot, with every exchange kept for inspection."""

    inner: SimpleSimulatedRobot
    exchanges: list[tuple[float, Command, Telemetry, float]] = field(default_factory=list)

    def exchange(self, command: Command, now_s: float) -> Telemetry:
        telemetry = self.inner.exchange(command, now_s)
        self.exchanges.append((now_s, command, telemetry, self.inner.true_velocity_signed_mps))
        return telemetry


@pytest.fixture
def agent_config(tmp_path: Path) -> AgentConfig:
    # The kinematic model: these tests drive the clock by hand, which the radio chain (real
    # time on its emulated air) does not follow. Integration tests run the full chain.
    return AgentConfig(token=TOKEN, data_dir=tmp_path / "agent", robot="simple")


@pytest.fixture
def robot(agent_config: AgentConfig) -> RecordingRobot:
    return RecordingRobot(
        SimpleSimulatedRobot(
            max_velocity_mps=agent_config.max_velocity_mps,
            max_accel_mps2=agent_config.max_accel_mps2,
            rail_length_m=agent_config.rail_length_m,
            seed=1,
        )
    )


@pytest.fixture
def app(agent_config: AgentConfig, robot: RecordingRobot) -> Iterator[Flask]:
    app = create_app(agent_config, start_control_loop=False, robot=robot)
    yield app
    get_runtime(app).close()


@pytest.fixture
def runtime(app: Flask) -> AgentRuntime:
    return get_runtime(app)


@pytest.fixture
def client(app: Flask) -> FlaskClient:
    return app.test_client()


@pytest.fixture
def auth() -> dict[str, str]:
    return {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture
def drive(runtime: AgentRuntime) -> Callable[[float, float], float]:
    """``drive(from_s, to_s)`` ticks the manager at 20 Hz on absolute deadlines over
    ``[from_s, to_s)``; returns the time of the next tick."""

    def _drive(from_s: float, to_s: float) -> float:
        k = 0
        now_s = from_s
        while now_s < to_s:
            runtime.manager.tick(now_s)
            k += 1
            now_s = from_s + k * PERIOD_S
        return now_s

    return _drive


@pytest.fixture
def soon() -> float:
    """A start time safely in the future of the real clock (PUT checks end_at against it)."""
    return round(time.time()) + 60.0
