"""``GET /healthz``: liveness for process supervisors and load balancers; no token, no detail."""

from __future__ import annotations

from flask import Blueprint, Response, jsonify

from basestation.runtime import get_runtime

bp = Blueprint("health", __name__)


@bp.get("/healthz")
def healthz() -> tuple[Response, int]:
    runtime = get_runtime()
    loop = runtime.control_loop
    # Unhealthy only when a loop was started and has died (the robot gets no commands), or
    # the store writer has (samples are no longer stored).
    ok = (loop is None or loop.running) and runtime.manager.writer.alive
    return jsonify({"ok": ok}), 200 if ok else 503
