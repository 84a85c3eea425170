"""``GET /api/v1/status``: what the agent and the robot are doing now."""

from __future__ import annotations

import time
from typing import Any

from flask import Blueprint, jsonify
from flask.typing import ResponseReturnValue

from basestation.runtime import AGENT_VERSION, get_runtime

bp = Blueprint("status", __name__)

# No telemetry for longer than this and the link counts as down (the firmware's dead-man
# stops the robot after 0.5 s without a command, so by then it is not under our control).
LINK_DOWN_AFTER_S = 1.0


@bp.get("/status")
def status() -> ResponseReturnValue:
    runtime = get_runtime()
    now_s = time.time()
    snapshot = runtime.manager.snapshot
    telemetry = snapshot.telemetry
    robot: dict[str, Any] = {"velocity_mps": None, "direction": None, "track_m": None}
    if telemetry is not None:
        robot = {
            "velocity_mps": telemetry.velocity_mps,
            "direction": telemetry.direction,
            "track_m": telemetry.track_m,
        }
    age_s = None if snapshot.telemetry_at_s is None else max(0.0, now_s - snapshot.telemetry_at_s)
    control = runtime.control_stats()
    return jsonify(
        {
            "version": AGENT_VERSION,
            "clock": now_s,
            "resource": runtime.config.resource,
            "battery_v": snapshot.battery_v,
            "robot": robot,
            "link": {
                "state": "up" if age_s is not None and age_s <= LINK_DOWN_AFTER_S else "down",
                "age_s": age_s,
            },
            "current_run": snapshot.current_run,
            "control": {
                "hz": control.hz,
                "running": control.running,
                "ticks": control.ticks,
                "late_ticks": control.late_ticks,
            },
        }
    )
