"""The agent's robot from its configuration: one rail file for the agent and the simulator."""

from __future__ import annotations

import json
import time
from pathlib import Path

from basestation.config import AgentConfig
from basestation.robot import Command
from basestation.robots import build_robot
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
            telemetry = robot.exchange(Command(velocity_mps=0.0, direction="cw"), time.time())
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
