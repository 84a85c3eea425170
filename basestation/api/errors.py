"""Every error the agent answers is JSON: ``{"error": code, "detail": text, ...}``.

Domain exceptions map to status codes here and nowhere else.
"""

from __future__ import annotations

from typing import Any

from flask import Flask, Response, jsonify
from werkzeug.exceptions import HTTPException

from basestation.errors import RunConflict, RunNotFound, StorageFull
from basestation.program import FieldErrors, InvalidRunBody


def error_response(
    status: int,
    error: str,
    detail: str,
    *,
    headers: list[tuple[str, str]] | None = None,
    **extra: Any,
) -> Response:
    response = jsonify({"error": error, "detail": detail, **extra})
    response.status_code = status
    for name, value in headers or []:
        response.headers.add(name, value)
    return response


def invalid_response(
    fields: FieldErrors, detail: str = "The request has invalid fields."
) -> Response:
    return error_response(422, "invalid", detail, fields=fields)


def _http_error(exc: HTTPException) -> Response:
    status = exc.code or 500
    error = "internal" if status == 500 else (exc.name or "error").lower().replace(" ", "_")
    # Keep the exception's own headers (Allow on 405, WWW-Authenticate on 401), not its HTML type.
    headers = [(k, v) for k, v in exc.get_headers() if k.lower() != "content-type"]
    detail = exc.description or exc.name or "error"
    if status == 500:
        # Never echo internals; the traceback is in the agent's log.
        detail = "The agent failed to handle this request; see the agent's log."
    return error_response(status, error, detail, headers=headers)


def _invalid(exc: InvalidRunBody) -> Response:
    return invalid_response(exc.fields)


def _not_found(exc: RunNotFound) -> Response:
    return error_response(404, "not_found", str(exc))


def _conflict(exc: RunConflict) -> Response:
    return error_response(409, "conflict", exc.detail, conflict=exc.kind)


def _storage_full(exc: StorageFull) -> Response:
    # 507: a state of the agent that an operator can fix, after which a retry succeeds.
    return error_response(507, "insufficient_storage", exc.detail)


def register_error_handlers(app: Flask) -> None:
    # HTTPException also catches the InternalServerError Flask wraps unhandled errors in.
    app.register_error_handler(HTTPException, _http_error)
    app.register_error_handler(InvalidRunBody, _invalid)
    app.register_error_handler(RunNotFound, _not_found)
    app.register_error_handler(RunConflict, _conflict)
    app.register_error_handler(StorageFull, _storage_full)
