"""The robot's motion and link as the control loop last read them: in ``GET /status`` and in
each ``POST /control`` answer, so that a console holding a drive button sees the robot
respond at the rate it sends commands, without asking for the whole status as well."""

from __future__ import annotations

from typing import Any

from basestation.tick_rules import AgentSnapshot

# No telemetry for longer than this and the link counts as down (the firmware's dead-man
# stops the robot after 0.5 s without a command, so by then it is not under our control).
LINK_DOWN_AFTER_S = 1.0


def robot_json(snapshot: AgentSnapshot) -> dict[str, Any]:
    """Measured velocity, direction and track position, and what the loop commands."""
    telemetry = snapshot.telemetry
    command = snapshot.command
    return {
        "velocity_mps": None if telemetry is None else telemetry.velocity_mps,
        "direction": None if telemetry is None else telemetry.direction,
        "track_m": None if telemetry is None else telemetry.track_m,
        "commanded_velocity_mps": None if command is None else command.velocity_mps,
        "commanded_direction": None if command is None else command.direction,
    }


def link_age_s(snapshot: AgentSnapshot, now_s: float) -> float | None:
    """Seconds since the last telemetry frame; None before the first."""
    at_s = snapshot.telemetry_at_s
    return None if at_s is None else max(0.0, now_s - at_s)


def link_json(snapshot: AgentSnapshot, now_s: float) -> dict[str, Any]:
    age_s = link_age_s(snapshot, now_s)
    rssi = getattr(snapshot.telemetry, "rssi_dbm", None)
    return {
        "state": "up" if age_s is not None and age_s <= LINK_DOWN_AFTER_S else "down",
        "age_s": age_s,
        "loss_pct": snapshot.loss_pct,
        "rssi_dbm": rssi if isinstance(rssi, int | float) else None,
    }
