"""A request id for every HTTP call (the caller's ``X-Request-ID`` when it is a plain token,
else a new one), returned in the answer and named by every log line of the call, and one
access line per call (``basestation.access``: method, path, status, duration)."""

from __future__ import annotations

import logging
import time

from flask import Flask, Response, g, request

from basestation.contract import REQUEST_ID_HEADER, request_id_or_new
from basestation.logs import REQUEST_ID

access_log = logging.getLogger("basestation.access")


def _begin() -> None:
    g.request_id = request_id_or_new(request.headers.get(REQUEST_ID_HEADER))
    g.request_id_token = REQUEST_ID.set(g.request_id)
    g.started_s = time.perf_counter()


def _end(response: Response) -> Response:
    request_id = g.get("request_id")
    if request_id is None:  # refused before the first hook ran
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


def _forget(exc: BaseException | None) -> None:
    token = g.pop("request_id_token", None)
    if token is not None:
        REQUEST_ID.reset(token)


def register_request_ids(app: Flask) -> None:
    """First among the hooks: a call refused by the token check is logged with its id too."""
    app.before_request_funcs.setdefault(None, []).insert(0, _begin)
    app.after_request(_end)
    app.teardown_request(_forget)
