"""``GET /api/v1/rail``: the rail the robot drives, drawn for a map of the roof.

The geometry is the same configuration the control loop projects positions onto
(``AGENT_RAIL_FILE``, else the default rail); the answer is checked against the SHA-256 the
loop recorded when it read the file, so a file edited since the agent started is reported
instead of drawn. The kinematic model has no geometry: only the rail's length is known.
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

from flask import Blueprint, jsonify
from flask.typing import ResponseReturnValue

from basestation.api.errors import error_response
from basestation.runtime import get_runtime
from basestation.telemetry.rail import DEFAULT_RAIL_PATH, Rail, RailConfigError

bp = Blueprint("rail", __name__)


@functools.lru_cache(maxsize=4)
def _drawing(path: str | None, sha256: str) -> dict[str, object]:
    """The drawing of the rail file at ``path`` with these bytes (cached by their hash)."""
    return Rail.configured(path).drawing()


@bp.get("/rail")
def rail() -> ResponseReturnValue:
    runtime = get_runtime()
    facts, _ = runtime.provenance_facts()
    if facts is None:
        return error_response(503, "not_ready", "The control loop is starting; ask again.")
    rail_facts = facts["rail"]
    if rail_facts["name"] is None:
        return jsonify({"geometry": False, "length_m": rail_facts["length_m"]})
    file = runtime.config.rail_file
    try:
        data = Path(file or DEFAULT_RAIL_PATH).read_bytes()
    except OSError:
        data = b""
    if hashlib.sha256(data).hexdigest() != rail_facts["sha256"]:
        return error_response(
            409,
            "rail_changed",
            "The rail file changed since the agent started; restart the agent to use it.",
        )
    try:
        drawing = _drawing(None if file is None else str(file), rail_facts["sha256"])
    except RailConfigError as exc:  # the file was valid when the loop read it
        return error_response(409, "rail_changed", f"The rail file no longer reads: {exc}")
    return jsonify({"geometry": True, **drawing})
