"""Log lines: one JSON object a line in production, each with the request id of its work.

A request id names one piece of work across processes: the web's middleware
(``core/http.py`` ``RequestIdMiddleware``) takes it from the request's ``X-Request-ID`` or
makes one; a Celery task gets the id of whatever queued it, or one of its own
(``portal/celery.py``); the agent client sends it to the agent with every call
(``portal/runs/agents.py``), whose log line for that call names it.

JSON lines come from python-json-logger (a kept formatter, used the same way by the agent);
the only code here is the context variable and the filter that puts it on each record.
No Django here: the settings build the logging configuration from this module.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from contextvars import ContextVar
from typing import Any

from pythonjsonlogger.json import JsonFormatter

from basestation.contract import request_id_or_new

_REQUEST_ID: ContextVar[str | None] = ContextVar("request_id", default=None)
# The fields of a JSON line, besides the message's own extras (``logger.info(..., extra=)``).
JSON_FIELDS = ("asctime", "levelname", "name", "message", "request_id")


def current_request_id() -> str | None:
    """The id of the request or task this code runs for, or None outside any."""
    return _REQUEST_ID.get()


@contextlib.contextmanager
def request_id_bound(value: str | None = None) -> Iterator[str]:
    """Run the block as the work ``value`` names (a caller's id, checked), or a new one."""
    request_id = request_id_or_new(value)
    token = _REQUEST_ID.set(request_id)
    try:
        yield request_id
    finally:
        _REQUEST_ID.reset(token)


def bind_request_id(value: str | None = None) -> str:
    """Set the id for the rest of this context (a task's thread until ``unbind``)."""
    request_id = request_id_or_new(value)
    _REQUEST_ID.set(request_id)
    return request_id


def unbind_request_id() -> None:
    _REQUEST_ID.set(None)


class RequestIdFilter(logging.Filter):
    """Puts the current request id (``-`` outside any) on every record it passes."""

    def filter(self, record: logging.LogRecord) -> bool:
        if not hasattr(record, "request_id"):
            record.request_id = _REQUEST_ID.get() or "-"
        return True


def logging_config(*, json_lines: bool, level: str) -> dict[str, Any]:
    """The ``LOGGING`` dict: JSON lines (production) or plain text (development), each with
    the request id. Also takes over the servers' own loggers (granian, uvicorn), so that a
    production process writes only JSON."""
    formatter: dict[str, Any]
    if json_lines:
        formatter = {
            "()": "pythonjsonlogger.json.JsonFormatter",
            "fmt": list(JSON_FIELDS),
            "rename_fields": {"asctime": "time", "levelname": "level", "name": "logger"},
        }
    else:
        formatter = {"format": "%(asctime)s %(levelname)s %(name)s [%(request_id)s]: %(message)s"}
    config: dict[str, Any] = {
        "version": 1,
        "disable_existing_loggers": False,
        "filters": {"request_id": {"()": "core.logs.RequestIdFilter"}},
        "formatters": {"default": formatter},
        "handlers": {
            "console": {
                "class": "logging.StreamHandler",
                "formatter": "default",
                "filters": ["request_id"],
            }
        },
        "root": {"handlers": ["console"], "level": level},
        "loggers": {"django.db.backends": {"level": "WARNING"}},
    }
    if json_lines:
        # The servers configure these before Django does; here they become JSON too.
        for name in ("_granian", "uvicorn", "uvicorn.error"):
            config["loggers"][name] = {"handlers": ["console"], "propagate": False}
        for name in ("granian.access", "uvicorn.access"):
            config["loggers"][name] = {
                "handlers": ["console"],
                "propagate": False,
                "level": "INFO",
            }
    return config


def json_handler_formatter() -> logging.Formatter:
    """The production formatter, for handlers that another library set up (Celery's)."""
    return JsonFormatter(
        list(JSON_FIELDS),
        rename_fields={"asctime": "time", "levelname": "level", "name": "logger"},
    )
