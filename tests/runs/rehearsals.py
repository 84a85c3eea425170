"""The self-check's program driven by the agent on the simulated robot, healthy or worn, in
simulated time (``basestation.dryrun`` with a simulator configuration): the samples a check on
the roof would record, in seconds. Each rehearsal is made once per test process."""

from __future__ import annotations

import math
from dataclasses import replace
from functools import cache
from typing import Any

from basestation.dryrun import dry_run
from basestation.sim.config import GpsConfig, SimConfig
from basestation.sim.physics import BatteryConfig, PhysicsConfig
from basestation.telemetry.rail import Rail
from portal.runs.analysis import SampleColumns, SampleRow
from portal.runs.self_check import Program, self_check_program

MAX_VELOCITY_MPS = 1.0
MAX_ACCEL_MPS2 = 0.5
# A small rail (a square 5 m a side near the thesis centre): the lap takes 20 s, not 120.
_CENTRE = (40.6331, -8.6594)
_HALF_LAT = 2.5 / 111_195.0
_HALF_LON = _HALF_LAT / math.cos(math.radians(_CENTRE[0]))
RAIL = Rail.from_mapping(
    {
        "points": [
            {"lat": _CENTRE[0] + dy * _HALF_LAT, "lon": _CENTRE[1] + dx * _HALF_LON}
            for dy, dx in ((1, -1), (1, 1), (-1, 1), (-1, -1))
        ]
    }
)
HEALTHY = SimConfig(rail=RAIL)
# Each wear the self-check must notice, and the figure that should notice it.
WEARS: dict[str, tuple[SimConfig, str]] = {
    "wheel slip": (replace(HEALTHY, physics=PhysicsConfig(wheel_slip=0.15)), "tracking_error_mps"),
    "motor lag": (replace(HEALTHY, physics=PhysicsConfig(throttle_time_constant_s=0.6)), "lag_s"),
    "worn battery": (
        replace(HEALTHY, battery=BatteryConfig(internal_resistance_ohm=1.5)),
        "battery_sag_v",
    ),
    "no RTK fix": (replace(HEALTHY, gps=GpsConfig(fix="rtk_float")), "rtk_share"),
}


def program() -> Program:
    return self_check_program(
        max_velocity_mps=MAX_VELOCITY_MPS, max_accel_mps2=MAX_ACCEL_MPS2, lap_m=RAIL.length_m
    )


@cache
def rehearse(wear: str | None = None) -> dict[str, Any]:
    """The dry run's answer for the check on the healthy robot, or with ``wear``."""
    sim = HEALTHY if wear is None else WEARS[wear][0]
    result = dry_run(
        program().segments,
        max_velocity_mps=MAX_VELOCITY_MPS,
        max_accel_mps2=MAX_ACCEL_MPS2,
        sim=sim,
    )
    assert result["state"] == "completed", result["reason"]
    return result


def columns(samples: list[dict[str, Any]]) -> SampleColumns:
    """The agent's samples as the analysis reads them: its ``SampleRow`` columns, ``t_s``
    from the first sample."""
    t0 = samples[0]["t"]
    return SampleColumns.from_rows(
        SampleRow(*(s["t"] - t0 if name == "t_s" else s[name] for name in SampleRow._fields))
        for s in samples
    )
