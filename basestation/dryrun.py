"""A dry run: a program run on a simulated robot of its own, in simulated time.

``python -m basestation.dryrun`` reads one JSON object on standard input::

    {"segments": [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 10}, ...],
     "limits": {"max_velocity_mps": 1.0, "max_accel_mps2": 0.5},
     "rail_length_m": 120.0}

and writes one JSON object to standard output: ``{"state", "reason", "rail_length_m",
"control_hz", "samples": [...]}``, the samples as an agent's API sends them (docs/agent-api.md).

The same code as a real run drives it: the program is checked and staged as ``PUT /runs/{id}``
does, and the run manager ticks it at the agent's control rate, starting, ramping, sampling and
braking as it would on the roof. Only the robot differs: the kinematic model (``robot =
"simple"``), on a clock this module moves, so a ten-minute program takes seconds. Nothing
here opens a radio, a network connection or a portal's resource: the only robot it can reach
is the model it builds (``tests/test_architecture.py`` holds it to that).
"""

from __future__ import annotations

import json
import secrets
import sys
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Final

from basestation.config import AgentConfig
from basestation.program import InvalidRunBody, parse_run_body
from basestation.robot import Robot
from basestation.robots import radio_robot
from basestation.runtime import AgentRuntime
from basestation.sim.clock import FakeClock
from basestation.sim.config import SimConfig
from basestation.sim.spi import SimulatedSpiConfig, make_simulated_spi

RUN_ID: Final = "dry-run"
# Staged this long before its start, as the portal stages a booked run ahead of it.
LEAD_S: Final = 1.0
# Ticks past the program's end for the robot to brake and the run to close.
BRAKE_S: Final = 5.0
# The longest program a dry run takes: a model is cheap, but not free.
MAX_PROGRAM_S: Final = 3600.0
SAMPLES_PAGE: Final = 5000
# On the simulated robot: its clock starts this long before the staging, for its GPS to
# find a fix and its battery filter to fill, as a robot switched on before its run.
SIM_WARM_UP_S: Final = 3.0


class DryRunRefused(ValueError):
    """The program or its limits cannot be run; the message says why."""


def _iso(epoch_s: float) -> str:
    return datetime.fromtimestamp(epoch_s, tz=UTC).isoformat()


def dry_run(
    segments: list[dict[str, Any]],
    *,
    max_velocity_mps: float,
    max_accel_mps2: float,
    rail_length_m: float = 120.0,
    start_s: float = 1_900_000_000.0,
    sim: SimConfig | None = None,
) -> dict[str, Any]:
    """Run ``segments`` on the kinematic model from ``start_s`` (epoch seconds, simulated);
    raise :class:`DryRunRefused` for a program the agent would refuse.

    With ``sim``, on the simulated robot instead (its firmware core, physics, GPS and radio,
    on its rail, which replaces ``rail_length_m``), through the agent's own radio driver and
    link, all on one simulated clock: what a run on the roof would record, worn parts and
    all (``[physics] wheel_slip``, ...), in seconds of wall time."""
    try:
        program_s = sum(float(s["duration_s"]) for s in segments)
    except (KeyError, TypeError, ValueError) as exc:
        raise DryRunRefused("every segment needs a duration_s in seconds") from exc
    if program_s > MAX_PROGRAM_S:
        raise DryRunRefused(f"a dry run takes programs of at most {MAX_PROGRAM_S:.0f} s")
    body = {
        "owner": "dry-run",
        "title": "dry run",
        "start_at": _iso(start_s),
        "end_at": _iso(start_s + program_s + BRAKE_S),
        "segments": segments,
        "limits": {"max_velocity_mps": max_velocity_mps, "max_accel_mps2": max_accel_mps2},
    }
    try:
        spec = parse_run_body(body)
    except InvalidRunBody as exc:
        problems = "; ".join(f"{field}: {', '.join(m)}" for field, m in sorted(exc.fields.items()))
        raise DryRunRefused(f"the program was refused: {problems}") from exc

    if sim is not None:
        rail_length_m = sim.rail.length_m
    with tempfile.TemporaryDirectory(prefix="dry-run-") as data_dir:
        config = AgentConfig(
            token=secrets.token_urlsafe(16),
            data_dir=Path(data_dir),
            robot="simple" if sim is None else "sim",
            max_velocity_mps=max(max_velocity_mps, 0.01),
            max_accel_mps2=max(max_accel_mps2, 0.01),
            rail_length_m=rail_length_m,
        )
        clock = FakeClock(start_s - LEAD_S - SIM_WARM_UP_S)
        robot = None if sim is None else _simulated_robot(config, sim, clock)
        # The store is deleted with its directory: nothing to keep through a power cut.
        runtime = AgentRuntime.open(config, robot=robot, durable=False)
        try:
            runtime.store.stage_run(RUN_ID, spec, now_s=start_s - LEAD_S, admit=lambda _: None)
            manager = runtime.manager
            manager.notify_runs_changed()
            period_s = 1.0 / config.control_hz
            ticks = round((LEAD_S + program_s + BRAKE_S) / period_s)
            for k in range(ticks + 1):
                tick_s = start_s - LEAD_S + k * period_s
                clock.set(max(clock.now_s, tick_s))  # the robot's world moves to the tick
                manager.tick(tick_s)
            manager.writer.flush()
            record = runtime.store.get_run(RUN_ID)
            samples: list[dict[str, Any]] = []
            while True:
                after = samples[-1]["seq"] if samples else 0
                page = runtime.store.samples_after(RUN_ID, after, SAMPLES_PAGE)
                samples.extend(sample.to_json_dict() for sample in page)
                if len(page) < SAMPLES_PAGE:
                    break
        finally:
            runtime.close()
    return {
        "state": record.state if record is not None else "failed",
        "reason": (record.reason or "") if record is not None else "the run was not staged",
        "rail_length_m": rail_length_m,
        "control_hz": config.control_hz,
        "samples": samples,
    }


def _simulated_robot(config: AgentConfig, sim: SimConfig, clock: FakeClock) -> Robot:
    """The simulated robot in this process on ``clock``, behind the agent's radio driver."""
    spi = make_simulated_spi(SimulatedSpiConfig(sim=sim, clock=clock))
    # The robot's GPS finds its fix while the clock moves to the first tick.
    return radio_robot(config, spi, sim.rail, clock=clock, sleep=clock.sleep)


def main() -> int:
    try:
        request = json.load(sys.stdin)
        result = dry_run(
            request["segments"],
            max_velocity_mps=float(request["limits"]["max_velocity_mps"]),
            max_accel_mps2=float(request["limits"]["max_accel_mps2"]),
            rail_length_m=float(request.get("rail_length_m", 120.0)),
        )
    except (ValueError, KeyError, TypeError) as exc:
        json.dump({"state": "failed", "reason": str(exc), "samples": []}, sys.stdout)
        return 2
    json.dump(result, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
