"""``GET /api/v1/logs/{YYYY-MM-DD}``: the daily usage log (who had the robot, when).

The thesis's agent wrote one log file a day; here the log is read from the run store (runs
that moved the robot, and manual control sessions), so it cannot disagree with the runs.
Days are UTC days, like every time the agent answers. The date never reaches the file
system: anything but a valid ``YYYY-MM-DD`` is refused before a query is built.
"""

from __future__ import annotations

import io
import re
from datetime import UTC, date, datetime, timedelta

from flask import Blueprint, Response, jsonify, request
from flask.typing import ResponseReturnValue

from basestation.api.errors import invalid_response
from basestation.contract import CsvWriter
from basestation.runtime import get_runtime

bp = Blueprint("logs", __name__)

_DAY = re.compile(r"[0-9]{4}-[0-9]{2}-[0-9]{2}")
LOG_CSV_COLUMNS = ("user", "title", "start", "end", "kind", "run_id", "state")


@bp.get("/logs/<day>")
def day_log(day: str) -> ResponseReturnValue:
    parsed = _parse_day(day)
    if parsed is None:
        return invalid_response(
            {"date": ["must be a calendar date written YYYY-MM-DD"]},
            "The log is addressed by its UTC date.",
        )
    start = datetime(parsed.year, parsed.month, parsed.day, tzinfo=UTC)
    try:
        end = start + timedelta(days=1)
    except OverflowError:
        end = datetime.max.replace(tzinfo=UTC)
    entries = get_runtime().store.usage_between(start.timestamp(), end.timestamp())
    rows = [entry.to_json_dict() for entry in entries]

    wants = request.accept_mimetypes.best_match(["application/json", "text/csv"])
    if wants == "text/csv":
        buffer = io.StringIO()
        writer = CsvWriter(buffer)
        writer.writerow(LOG_CSV_COLUMNS)
        for row in rows:
            writer.writerow([row[c] for c in LOG_CSV_COLUMNS])
        response = Response(buffer.getvalue(), mimetype="text/csv")
    else:
        response = jsonify({"date": parsed.isoformat(), "timezone": "UTC", "entries": rows})
    response.vary.add("Accept")
    return response


def _parse_day(text: str) -> date | None:
    if not _DAY.fullmatch(text):
        return None
    try:
        return date.fromisoformat(text)
    except ValueError:
        return None
