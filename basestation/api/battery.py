"""``GET /api/v1/battery``: the battery voltage, filtered and raw (the thesis's ``/bat``)."""

from __future__ import annotations

import time

from flask import Blueprint, jsonify
from flask.typing import ResponseReturnValue

from basestation.manager import BATTERY_WINDOW
from basestation.runtime import get_runtime

bp = Blueprint("battery", __name__)


@bp.get("/battery")
def battery() -> ResponseReturnValue:
    runtime = get_runtime()
    snapshot = runtime.control.snapshot
    at_s = snapshot.telemetry_at_s
    threshold_v = runtime.config.low_battery_v
    return jsonify(
        {
            "filtered_v": snapshot.battery_v,
            "raw_v": snapshot.battery_raw_v,
            "window": BATTERY_WINDOW,
            "age_s": None if at_s is None else max(0.0, time.time() - at_s),
            "low_battery_v": threshold_v if threshold_v > 0 else None,
            "low": snapshot.battery_low,
        }
    )
