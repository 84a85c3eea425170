"""The agent's log lines: plain text or one JSON object a line (``AGENT_LOG_FORMAT``), each
naming the request id of the HTTP call it belongs to (``basestation/api/access.py`` sets it
from the caller's ``X-Request-ID``), so a portal request or task and the agent's answer to it
can be found together. python-json-logger writes the JSON, as on the portal.

No Flask here: the control loop's process configures its logging from this module too, and
starts faster without importing the web framework.
"""

from __future__ import annotations

import logging
import sys
from contextvars import ContextVar

from pythonjsonlogger.json import JsonFormatter

LOG_FORMATS = ("plain", "json")
# The request id of the HTTP call this thread is answering; None outside any.
REQUEST_ID: ContextVar[str | None] = ContextVar("agent_request_id", default=None)
# What configure_logging last set: the control loop's process is told the same.
_configured = {"format": "plain"}


class RequestIdFilter(logging.Filter):
    """The request id of the HTTP call being answered (``-`` in the loop and at start)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if not hasattr(record, "request_id"):
            record.request_id = REQUEST_ID.get() or "-"
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
