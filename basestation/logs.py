"""The agent's log lines: plain text or one JSON object a line (``AGENT_LOG_FORMAT``), and a
line for every HTTP call with the request id the caller sent (``X-Request-ID``, see
``basestation/contract.py``) or one made here, so a portal request or task and the agent's
answer to it can be found together. python-json-logger writes the JSON, as on the portal."""

from __future__ import annotations

import logging
import sys
import time

from flask import Flask, Response, g, has_request_context, request
from pythonjsonlogger.json import JsonFormatter

from basestation.contract import REQUEST_ID_HEADER, request_id_or_new

LOG_FORMATS = ("plain", "json")
access_log = logging.getLogger("basestation.access")
# What configure_logging last set: the control loop's process is told the same.
_configured = {"format": "plain"}


class RequestIdFilter(logging.Filter):
    """The request id of the HTTP call being answered (``-`` in the loop and at start)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if not hasattr(record, "request_id"):
            record.request_id = g.get("request_id", "-") if has_request_context() else "-"
        return True


def current_log_format() -> str:
    return _configured["format"]


def configure_logging(*, level: int | str, log_format: str) -> None:
    """Every line to standard error, with its request id."""
    _configured["format"] = log_format
    handler = logging.StreamHandler(sys.stderr)
    handler.addFilter(RequestIdFilter())
    if log_format == "json":
        handler.setFormatter(
            JsonFormatter(
                ["asctime", "levelname", "name", "message", "request_id"],
                rename_fields={"asctime": "time", "levelname": "level", "name": "logger"},
            )
        )
    else:
        handler.setFormatter(
            logging.Formatter("%(asctime)s %(levelname)s %(name)s [%(request_id)s]: %(message)s")
        )
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper() if isinstance(level, str) else level)


def _begin() -> None:
    g.request_id = request_id_or_new(request.headers.get(REQUEST_ID_HEADER))
    g.started_s = time.perf_counter()


def _end(response: Response) -> Response:
    request_id = g.get("request_id")
    if request_id is None:  # a request refused before the first hook ran
        return response
    response.headers[REQUEST_ID_HEADER] = request_id
    access_log.info(
        "%s %s %s",
        request.method,
        request.full_path.rstrip("?"),
        response.status_code,
        extra={
            "method": request.method,
            "path": request.path,
            "status": response.status_code,
            "duration_ms": round((time.perf_counter() - g.started_s) * 1000, 1),
        },
    )
    return response


def register_request_ids(app: Flask) -> None:
    """First among the hooks: a call refused by the token check is logged with its id too."""
    app.before_request_funcs.setdefault(None, []).insert(0, _begin)
    app.after_request(_end)
