"""Admin operations: ``POST /control`` (manual drive), ``POST /stop`` and ``/stop/release``.

Only the control token reaches ``/control`` and ``/stop/release`` (the read-only token may
stop: :mod:`basestation.api.auth`); that only admins reach them is the portal's business (it
calls them only for admins and passes the admin's name as ``user``, for the usage log).
"""

from __future__ import annotations

import time
from typing import Any

from flask import Blueprint, jsonify, request
from flask.typing import ResponseReturnValue

from basestation.api.bodies import json_body
from basestation.api.readings import link_json, robot_json
from basestation.manual import (
    MAX_STOP_BODY_BYTES,
    RELEASE_FIELDS,
    parse_control_body,
    parse_stop_body,
    stop_request_from,
)
from basestation.runtime import get_runtime
from basestation.services import estop_latch, estop_release, manual_drive
from basestation.tick_rules import EstopLatch

bp = Blueprint("control", __name__)


def estop_json(latch: EstopLatch | None) -> dict[str, Any]:
    if latch is None:
        return {"latched": False, "since": None, "reason": None}
    return latch.to_json_dict()


@bp.post("/control")
def control() -> ResponseReturnValue:
    runtime = get_runtime()
    command = parse_control_body(json_body(), max_velocity_mps=runtime.config.max_velocity_mps)
    now_s = time.time()
    drive, aborted = manual_drive(manager=runtime.control, command=command, now_s=now_s)
    # The robot as the loop last read it: a console repeating its command a few times a second
    # sees the robot respond at that rate from the answers alone.
    snapshot = runtime.control.snapshot
    return jsonify(
        {
            "manual": None if drive is None else drive.to_json_dict(now_s),
            "aborted_run": aborted,
            "clock": now_s,
            "robot": robot_json(snapshot),
            "link": link_json(snapshot, now_s),
        }
    )


def stop_body() -> bytes:
    """At most :data:`MAX_STOP_BODY_BYTES` of the body, whatever its type or declared length:
    a stop never waits for, nor is refused for, the rest (:func:`refuse_oversized_body`
    lets it through)."""
    length = request.content_length
    wanted = MAX_STOP_BODY_BYTES if length is None else min(length, MAX_STOP_BODY_BYTES)
    data = request.environ["wsgi.input"].read(wanted) if wanted > 0 else b""
    return data if isinstance(data, bytes) else b""


@bp.post("/stop")
def stop() -> ResponseReturnValue:
    """Refused for nothing but its token: see :func:`stop_request_from`."""
    runtime = get_runtime()
    request_ = stop_request_from(stop_body())
    latch, aborted = estop_latch(manager=runtime.control, request=request_, now_s=time.time())
    return jsonify(
        {
            "estop": estop_json(latch),
            "aborted_run": aborted,
            "truncated": list(request_.truncated),
            "ignored": list(request_.ignored),
        }
    )


@bp.post("/stop/release")
def release() -> ResponseReturnValue:
    runtime = get_runtime()
    request_ = parse_stop_body(json_body(optional=True), allowed=RELEASE_FIELDS)
    was_latched = estop_release(manager=runtime.control, request=request_, now_s=time.time())
    return jsonify({"estop": estop_json(runtime.control.estop), "released": was_latched})
