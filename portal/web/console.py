"""The robot console's downloads: the base station's daily use log as CSV."""

from __future__ import annotations

import re
from datetime import date
from typing import Final

from django.core.exceptions import BadRequest
from django.http import HttpRequest, HttpResponse
from django.shortcuts import get_object_or_404

from basestation.contract import CsvWriter
from bookings.models import Resource
from core.accounts.staff import staff_required
from portal.runs.services.robot import robot_day_log

# The agent's own CSV columns (basestation/api/logs.py; tests/web/test_console.py holds the
# two to the same list).
DAY_LOG_COLUMNS: Final = ("user", "title", "start", "end", "kind", "run_id", "state")


@staff_required
def robot_log_csv(request: HttpRequest, name: str) -> HttpResponse:
    """``?day=YYYY-MM-DD`` (a UTC day, as the base station keeps its log) as a CSV file."""
    resource = get_object_or_404(Resource, name=name, kind="mobile")
    text = request.GET.get("day", "")
    try:
        if not re.fullmatch(r"\d{4}-\d{2}-\d{2}", text):
            raise ValueError(text)
        day = date.fromisoformat(text)
    except ValueError as exc:
        raise BadRequest("The day is YYYY-MM-DD.") from exc
    log = robot_day_log(resource=resource, by=request.user, day=day)  # type: ignore[arg-type]
    response = HttpResponse(content_type="text/csv; charset=utf-8")
    response["Content-Disposition"] = f'attachment; filename="{resource.name}-log-{day}.csv"'
    writer = CsvWriter(response)
    writer.writerow(DAY_LOG_COLUMNS)
    for entry in log["entries"]:
        writer.writerow([entry.get(c) for c in DAY_LOG_COLUMNS])
    return response
