"""Reading JSON request bodies the same way on every endpoint."""

from __future__ import annotations

import json

from flask import request
from werkzeug.exceptions import UnsupportedMediaType

from basestation.program import InvalidRunBody


def json_body(*, optional: bool = False) -> object:
    """The decoded JSON body; ``None`` for an empty body when ``optional``.

    A body that is not labelled JSON is 415; one that does not decode is 422 (``body``).
    The size limit (64 KiB, 413) is Flask's ``MAX_CONTENT_LENGTH``.
    """
    data = request.get_data(cache=False)
    if optional and not data:
        return None
    if not request.is_json:
        raise UnsupportedMediaType("Send the body as JSON (Content-Type: application/json).")
    return decode_json(data)


def decode_json(data: bytes) -> object:
    def reject_constant(name: str) -> object:
        raise ValueError(f"{name} is not a JSON number")

    try:
        return json.loads(data.decode("utf-8"), parse_constant=reject_constant)
    except UnicodeDecodeError:
        raise InvalidRunBody({"body": ["must be UTF-8 encoded JSON"]}) from None
    except RecursionError:
        raise InvalidRunBody({"body": ["is nested too deeply"]}) from None
    except ValueError as exc:  # JSONDecodeError is a ValueError
        raise InvalidRunBody({"body": [f"is not valid JSON: {exc}"]}) from None
