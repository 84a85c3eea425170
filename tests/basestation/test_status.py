"""``GET /status`` beyond the runs: the base station's own health, the control loop's timing."""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
from flask import Flask
from flask.testing import FlaskClient

from basestation import system
from basestation.api.status import LINK_FAULT_AFTER_S, faults
from basestation.app import create_app
from basestation.config import AgentConfig
from basestation.control import ControlStats
from basestation.runtime import get_runtime
from basestation.system import _TIME_ERROR, cpu_temp_c
from tests.basestation.conftest import RecordingRobot


def _app_with(config: AgentConfig, robot: RecordingRobot) -> Iterator[Flask]:
    app = create_app(config, start_control_loop=False, robot=robot)
    yield app
    get_runtime(app).close()


@pytest.fixture
def thermal_zone(tmp_path: Path) -> Path:
    path = tmp_path / "temp"
    path.write_text("48300\n", encoding="ascii")  # the thesis's Pi, with its fan
    return path


def test_status_reports_the_cpu_temperature_from_the_thermal_zone(
    agent_config: AgentConfig, robot: RecordingRobot, auth: dict[str, str], thermal_zone: Path
) -> None:
    for app in _app_with(replace(agent_config, cpu_temp_path=thermal_zone), robot):
        status = app.test_client().get("/api/v1/status", headers=auth).json
        assert status is not None
        assert status["host"]["cpu_temp_c"] == 48.3


def test_status_reports_null_without_a_thermal_zone(
    agent_config: AgentConfig, robot: RecordingRobot, auth: dict[str, str], tmp_path: Path
) -> None:
    for app in _app_with(replace(agent_config, cpu_temp_path=tmp_path / "absent"), robot):
        response = app.test_client().get("/api/v1/status", headers=auth)
        assert response.status_code == 200
        assert response.json is not None
        assert response.json["host"]["cpu_temp_c"] is None


@pytest.mark.parametrize("content", ["", "hot", "\xff"])
def test_an_unreadable_thermal_zone_reads_as_null(tmp_path: Path, content: str) -> None:
    path = tmp_path / "temp"
    path.write_bytes(content.encode("latin-1"))
    assert cpu_temp_c(path) is None


@pytest.mark.parametrize(
    ("adjtimex_state", "reported"),
    [(0, True), (1, True), (_TIME_ERROR, False), (-1, None)],  # TIME_OK, TIME_INS, ..., failed
)
def test_status_reports_the_clock_and_whether_the_kernel_says_it_is_synchronised(
    client: FlaskClient,
    auth: dict[str, str],
    monkeypatch: pytest.MonkeyPatch,
    adjtimex_state: int,
    reported: bool | None,
) -> None:
    # The kernel's answer is faked (this machine may or may not run an NTP daemon): the API
    # must report what adjtimex(2) says, not what this machine happens to be.
    monkeypatch.setattr(system._clock, "_adjtimex", lambda buffer: adjtimex_state)
    before_s = time.time()
    status = client.get("/api/v1/status", headers=auth).json
    after_s = time.time()
    assert status is not None
    assert before_s <= status["clock"] <= after_s
    assert status["clock_synchronized"] is reported


def test_without_adjtimex_the_clock_sync_state_is_unknown(
    client: FlaskClient, auth: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(system._clock, "_adjtimex", None)
    status = client.get("/api/v1/status", headers=auth).json
    assert status is not None
    assert status["clock_synchronized"] is None


def test_status_reports_battery_estop_manual_and_the_control_window(
    client: FlaskClient, auth: dict[str, str]
) -> None:
    status = client.get("/api/v1/status", headers=auth).json
    assert status is not None
    assert status["battery"] == {
        "filtered_v": None,
        "raw_v": None,
        "low_battery_v": 50.0,
        "low": False,
    }
    assert status["estop"] == {"latched": False, "since": None, "reason": None}
    assert status["manual"] is None
    control = status["control"]
    assert control["missed_ticks"] == 0
    assert control["window"]["seconds"] == 60.0
    assert set(control["window"]) == {
        "seconds",
        "ticks",
        "lateness_p50_ms",
        "lateness_p99_ms",
        "lateness_max_ms",
        "tick_p50_ms",
        "tick_p99_ms",
        "tick_max_ms",
    }


def _control(*, running: bool, ticks: int, hz: float = 20.0) -> ControlStats:
    return ControlStats(
        hz=hz,
        running=running,
        ticks=ticks,
        late_ticks=0,
        skipped_ticks=0,
        tick_errors=0,
        max_lateness_s=0.0,
    )


def test_no_faults_while_the_loop_runs_and_the_robot_answers(
    client: FlaskClient, auth: dict[str, str]
) -> None:
    status = client.get("/api/v1/status", headers=auth).json
    assert status is not None
    assert status["faults"] == []  # driven by hand: no loop to judge
    assert (
        faults(loop_started=True, control=_control(running=True, ticks=500), link_age_s=0.05) == []
    )


def test_a_stopped_control_loop_is_a_fault() -> None:
    found = faults(loop_started=True, control=_control(running=False, ticks=500), link_age_s=0.05)
    assert found == ["control loop stopped"]


def test_a_robot_silent_for_longer_than_a_blip_is_a_fault() -> None:
    silent_s = LINK_FAULT_AFTER_S + 2
    found = faults(
        loop_started=True, control=_control(running=True, ticks=500), link_age_s=silent_s
    )
    assert found == [f"robot not answering (no telemetry for {silent_s:.0f} s)"]
    never = faults(loop_started=True, control=_control(running=True, ticks=500), link_age_s=None)
    assert never == ["robot not answering (no telemetry yet)"]
    # A lost frame or two, or a loop just started, is not.
    assert (
        faults(loop_started=True, control=_control(running=True, ticks=500), link_age_s=2.0) == []
    )
    assert (
        faults(loop_started=True, control=_control(running=True, ticks=10), link_age_s=None) == []
    )
