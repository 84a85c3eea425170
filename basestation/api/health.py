"""``GET /healthz``: liveness for process supervisors and load balancers; no token, no detail."""

from __future__ import annotations

from flask import Blueprint, Response, jsonify

from basestation.runtime import get_runtime

bp = Blueprint("health", __name__)


@bp.get("/healthz")
def healthz() -> tuple[Response, int]:
    runtime = get_runtime()
    # Unhealthy only when the loop is not ticking (its process died or hangs: the robot gets
    # no commands), or its store writer has died (samples are no longer stored).
    ok = runtime.loop_healthy()
    return jsonify({"ok": ok}), 200 if ok else 503
