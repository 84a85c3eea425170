"""The agent's robot from its configuration: one rail file for the agent and the simulator."""

from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path

import pytest

from basestation.config import AgentConfig, ConfigError
from basestation.robot import Command, RobotLimits, RobotLinkError
from basestation.robots import build_robot, reply_timeout_s
from basestation.telemetry.rail import Rail

CENTRE = {"lat": 40.634172, "lon": -8.660015}
# A 40 m x 10 m rectangle around the building centre: nowhere near the default rail's
# corners, which stand 21 m north, east, south and west of the centre.
M_PER_DEG_LAT = 111_195.0
M_PER_DEG_LON = M_PER_DEG_LAT * 0.7589


def _corner(east_m: float, north_m: float) -> dict[str, float]:
    return {
        "lat": CENTRE["lat"] + north_m / M_PER_DEG_LAT,
        "lon": CENTRE["lon"] + east_m / M_PER_DEG_LON,
    }


def test_the_simulated_robot_drives_the_agents_rail_file(tmp_path: Path) -> None:
    corners = [_corner(-20, 5), _corner(20, 5), _corner(20, -5), _corner(-20, -5)]
    rail_file = tmp_path / "rail.json"
    rail_file.write_text(json.dumps({"centre": CENTRE, "points": corners}))
    rail = Rail.from_file(rail_file)
    robot = build_robot(
        AgentConfig(token="t" * 32, data_dir=tmp_path / "agent", robot="sim", rail_file=rail_file)
    )
    try:
        deadline_s = time.monotonic() + 10.0
        telemetry = None
        while time.monotonic() < deadline_s:
            try:
                telemetry = robot.exchange(Command(velocity_mps=0.0, direction="cw"), time.time())
            except RobotLinkError:
                # An answer later than the link waits for (a busy test machine delays the
                # simulated robot's thread) is a lost exchange, as on the air: ask again.
                continue
            if getattr(telemetry, "position_known", False):
                break
            time.sleep(0.05)
        assert telemetry is not None
        assert telemetry.position_known, "no GPS fix from the simulated robot"
        # The robot's fix lies on the configured rail (within the simulated RTK noise); on the
        # default rail it would be some 16 m off this one.
        position = rail.project(telemetry.lat_deg, telemetry.lon_deg)
        assert abs(position.lateral_m) < 0.5, position
    finally:
        close = getattr(robot, "close", None)
        if close is not None:
            close()


def test_the_simulated_firmware_confirms_the_agents_limits_and_reports_its_hard_maximum(
    tmp_path: Path,
) -> None:
    robot = build_robot(
        AgentConfig(token="t" * 32, data_dir=tmp_path, robot="sim", max_velocity_mps=1.5)
    )
    try:
        assert getattr(robot, "limits", None) == RobotLimits(
            max_velocity_mps=1.5, max_accel_mps2=1.0, hard_max_velocity_mps=4.0
        )
    finally:
        getattr(robot, "close", lambda: None)()


@pytest.mark.parametrize(("hz", "timeout_ms"), [(20.0, 25.0), (50.0, 12.0)])
def test_the_reply_timeout_fits_the_control_period(
    tmp_path: Path, hz: float, timeout_ms: float
) -> None:
    assert reply_timeout_s(hz) * 1000 == pytest.approx(timeout_ms)
    # Command on air, the wait, and a few ms for the rest of the tick: within one period.
    assert 3.02 + timeout_ms + 3.0 < 1000 / hz
    robot = build_robot(AgentConfig(token="t" * 32, data_dir=tmp_path, robot="sim", control_hz=hz))
    try:
        link = getattr(robot, "link", None)
        assert link is not None
        assert link.reply_timeout_s == pytest.approx(timeout_ms / 1000)
    finally:
        getattr(robot, "close", lambda: None)()


def test_an_agent_limit_above_the_simulated_firmwares_hard_maximum_is_refused(
    tmp_path: Path,
) -> None:
    config = AgentConfig(token="t" * 32, data_dir=tmp_path, robot="sim", max_velocity_mps=4.5)
    with pytest.raises(ConfigError, match=r"=4.5 is above the robot's hard maximum 4 m/s"):
        build_robot(config)


BUILD_ID_HEADER = Path(__file__).resolve().parents[2] / "firmware" / "host" / "build" / "build_id.h"


def test_the_flashed_image_answers_the_agent_over_the_emulated_air(tmp_path: Path) -> None:
    """``sim-flashed``: robot.elf itself, on an emulated ATmega328P, confirms the agent's
    limits, names its build and answers each command of a second at 50 Hz, driving."""
    robot = build_robot(
        AgentConfig(token="t" * 32, data_dir=tmp_path, robot="sim-flashed", max_velocity_mps=1.5)
    )
    try:
        assert robot.limits == RobotLimits(
            max_velocity_mps=1.5, max_accel_mps2=1.0, hard_max_velocity_mps=4.0
        )
        assert robot.identity is not None
        assert robot.identity.build_id == BUILD_ID_HEADER.read_text().split('"')[1]
        # Commands at 50 Hz until fifty are answered: on a loaded machine an answer can miss
        # the tick's wait (a lost frame to the agent, as on the roof); the deadline only
        # bounds a hang.
        start_s = time.monotonic()
        answers = []
        for tick in range(1000):
            if len(answers) == 50:
                break
            time.sleep(max(0.0, start_s + tick * 0.02 - time.monotonic()))
            with contextlib.suppress(RobotLinkError):
                answers.append(
                    robot.exchange(Command(velocity_mps=0.5, direction="cw"), time.monotonic())
                )
        assert len(answers) == 50
        assert answers[-1].velocity_mps > 0.2  # up the firmware's ramp, clockwise
        assert answers[-1].direction == "cw"
        # The strength each command arrived with, as the image read it from its radio.
        assert len({answer.robot_rssi_dbm for answer in answers}) > 1
        assert all(-105 <= answer.robot_rssi_dbm < -30 for answer in answers)
    finally:
        robot.close()


def test_a_missing_image_or_an_override_it_cannot_take_is_a_clear_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("AMZ_ROBOT_ELF", str(tmp_path / "nowhere.elf"))
    with pytest.raises(
        ConfigError, match=r"nowhere\.elf does not exist: run `make -C firmware hex`"
    ):
        build_robot(AgentConfig(token="t" * 32, data_dir=tmp_path, robot="sim-flashed"))
    monkeypatch.delenv("AMZ_ROBOT_ELF")
    sim = tmp_path / "sim.toml"
    sim.write_text("[firmware]\ndead_man_ms = 300\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="the flashed image's is compiled in"):
        build_robot(
            AgentConfig(token="t" * 32, data_dir=tmp_path, robot="sim-flashed", sim_config=sim)
        )
