"""Request size limit on every endpoint, whether it reads a body or not."""

from __future__ import annotations

from flask import current_app, request
from werkzeug.exceptions import RequestEntityTooLarge

from basestation.contract import STOP_PATH


def refuse_oversized_body() -> None:
    """413 for a declared body over the limit before any handler runs.

    Flask enforces ``MAX_CONTENT_LENGTH`` only when a handler reads the body; an endpoint
    that ignores bodies would otherwise accept (and let the server buffer) any size.
    Bodies without a declared length are cut at the limit when read. A stop is never
    refused for its body: it reads what it needs and ignores the rest.
    """
    if request.method == "POST" and request.path == STOP_PATH:
        return
    limit = current_app.config["MAX_CONTENT_LENGTH"]
    length = request.content_length
    if limit is not None and length is not None and length > limit:
        raise RequestEntityTooLarge(too_large_detail(limit))


def too_large_detail(limit_bytes: int) -> str:
    """What a 413 says, here and from the HTTP server in front (``basestation.serve``)."""
    return f"The body is larger than {limit_bytes} bytes."
