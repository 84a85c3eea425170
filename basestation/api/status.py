"""``GET /api/v1/status``: what the agent, the robot and the base station are doing now."""

from __future__ import annotations

import time
from typing import Any

from flask import Blueprint, jsonify
from flask.typing import ResponseReturnValue

from basestation.api.control import estop_json
from basestation.api.readings import link_age_s, link_json, robot_json
from basestation.control import ControlStats
from basestation.loop_process import LoopProcess
from basestation.provenance import AGENT_VERSION
from basestation.runtime import get_runtime
from basestation.system import clock_sync, clock_synchronized, cpu_temp_c

bp = Blueprint("status", __name__)

# Down this long while the control loop runs, and it is a fault rather than a lost frame or
# two: the robot is off, out of range or its radio is broken. The portal stops bookings on it.
LINK_FAULT_AFTER_S = 5.0


def faults(*, loop_started: bool, control: ControlStats, link_age_s: float | None) -> list[str]:
    """What keeps this base station from running a program now, in words for an admin."""
    found = []
    if loop_started and not control.running:
        found.append("control loop stopped")
    elif (
        loop_started
        and control.ticks >= LINK_FAULT_AFTER_S * control.hz
        and (link_age_s is None or link_age_s > LINK_FAULT_AFTER_S)
    ):
        silent = "yet" if link_age_s is None else f"for {link_age_s:.0f} s"
        found.append(f"robot not answering (no telemetry {silent})")
    return found


def _ms(value_s: float | None) -> float | None:
    return None if value_s is None else round(value_s * 1000.0, 3)


def control_json(control: ControlStats, loop: LoopProcess | None = None) -> dict[str, Any]:
    window = control.window
    return {
        "hz": control.hz,
        # The loop's own process (None when the manager is ticked by hand), how often it was
        # started again after dying, and the scheduling it got (docs/basestation.md).
        "pid": None if loop is None else loop.pid,
        "restarts": 0 if loop is None else loop.restarts,
        "sched_fifo": loop is not None and loop.realtime,
        "cpu": None if loop is None else loop.pinned_cpu,
        "running": control.running,
        "ticks": control.ticks,
        "late_ticks": control.late_ticks,
        "missed_ticks": control.skipped_ticks,
        "tick_errors": control.tick_errors,
        "max_lateness_ms": _ms(control.max_lateness_s),
        "window": {
            "seconds": control.window_s,
            "ticks": window.ticks,
            "lateness_p50_ms": _ms(window.lateness_p50_s),
            "lateness_p99_ms": _ms(window.lateness_p99_s),
            "lateness_max_ms": _ms(window.lateness_max_s),
            "tick_p50_ms": _ms(window.duration_p50_s),
            "tick_p99_ms": _ms(window.duration_p99_s),
            "tick_max_ms": _ms(window.duration_max_s),
        },
    }


@bp.get("/status")
def status() -> ResponseReturnValue:
    return jsonify(status_document())


def status_document() -> dict[str, Any]:
    """What ``GET /status`` answers (and ``GET /metrics`` counts from)."""
    runtime = get_runtime()
    now_s = time.time()
    manager = runtime.control
    snapshot = manager.snapshot
    age_s = link_age_s(snapshot, now_s)
    disk = runtime.disk()
    manual = manager.manual(now_s)
    threshold_v = runtime.config.low_battery_v
    control = runtime.control_stats()
    agent, firmware = runtime.provenance_facts()
    return {
        "version": AGENT_VERSION,
        "clock": now_s,
        "clock_synchronized": clock_synchronized(),
        "clock_sync": clock_sync().to_json_dict(),
        "resource": runtime.config.resource,
        "battery_v": snapshot.battery_v,
        "battery": {
            "filtered_v": snapshot.battery_v,
            "raw_v": snapshot.battery_raw_v,
            "low_battery_v": threshold_v if threshold_v > 0 else None,
            "low": snapshot.battery_low,
        },
        "robot": robot_json(snapshot),
        "limits": runtime.limits_json(),
        "firmware": firmware,
        "rail": None if agent is None else agent["rail"],
        "link": link_json(snapshot, now_s),
        "current_run": snapshot.current_run,
        "manual": None if manual is None else manual.to_json_dict(now_s),
        "estop": estop_json(manager.estop),
        "host": {
            "cpu_temp_c": cpu_temp_c(runtime.config.cpu_temp_path),
            "disk_free_bytes": None if disk is None else disk.free_bytes,
            "disk_total_bytes": None if disk is None else disk.total_bytes,
        },
        "control": control_json(control, runtime.loop),
        "faults": faults(
            loop_started=runtime.loop_started,
            control=control,
            link_age_s=age_s,
        ),
    }
