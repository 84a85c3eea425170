"""Bodies of the admin operations: manual drive (``POST /control``) and the e-stop.

Parsed like run bodies: every problem is collected into field errors
(:class:`~basestation.program.InvalidRunBody`, answered 422), unknown fields are refused.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from basestation.contract import DIRECTIONS, Direction
from basestation.program import FieldErrors, InvalidRunBody, parse_number

# The dead-man of a manual command: a client that stops sending stops the robot within
# this. 10 s is the longest an admin may ask for; 1 s is what a UI holding a button sends.
MAX_MANUAL_TTL_S = 10.0
DEFAULT_MANUAL_TTL_S = 1.0
MAX_USER_CHARS = 150
# What the e-stop latch keeps of a stop's reason (the portal's audit keeps the whole of it).
MAX_REASON_CHARS = 200
# A stop reads at most this much of its body (the rest is left unread, never refused).
MAX_STOP_BODY_BYTES = 64 * 1024

_LONE_SURROGATE = re.compile("[\ud800-\udfff]")

CONTROL_FIELDS = frozenset({"user", "velocity_mps", "direction", "ttl_s", "force"})
STOP_FIELDS = frozenset({"user", "reason"})
RELEASE_FIELDS = frozenset({"user"})


@dataclass(frozen=True)
class ManualCommand:
    user: str
    velocity_mps: float
    direction: Direction
    ttl_s: float
    force: bool


@dataclass(frozen=True)
class StopRequest:
    user: str | None
    reason: str | None
    # What a stop did not keep of its body, so that its answer can say so: fields cut to what
    # the latch stores, and fields (or the whole body, ``"body"``) it did not read.
    truncated: tuple[str, ...] = ()
    ignored: tuple[str, ...] = ()


def parse_control_body(raw: object, *, max_velocity_mps: float) -> ManualCommand:
    errors: FieldErrors = {}
    if not isinstance(raw, Mapping):
        raise InvalidRunBody({"body": ["must be a JSON object"]})
    _unknown(raw, CONTROL_FIELDS, errors)
    user = _text(raw, "user", MAX_USER_CHARS, errors, required=True)
    velocity = parse_number(raw, "velocity_mps", errors)
    if velocity is not None:
        if velocity < 0:
            _add(errors, "velocity_mps", "must not be negative")
        elif velocity > max_velocity_mps:
            _add(
                errors,
                "velocity_mps",
                f"{velocity:g} m/s is above this robot's maximum {max_velocity_mps:g} m/s",
            )
    direction = raw.get("direction")
    if "direction" not in raw:
        _add(errors, "direction", "is required")
    elif direction not in DIRECTIONS:
        _add(errors, "direction", "must be 'cw' or 'ccw'")
    ttl = parse_number(raw, "ttl_s", errors, required=False)
    if ttl is not None and not 0 < ttl <= MAX_MANUAL_TTL_S:
        _add(errors, "ttl_s", f"must be greater than 0 and at most {MAX_MANUAL_TTL_S:g} s")
    force = raw.get("force", False)
    if not isinstance(force, bool):
        _add(errors, "force", "must be true or false")
    if errors:
        raise InvalidRunBody(errors)
    assert user is not None
    assert velocity is not None
    assert direction in DIRECTIONS
    return ManualCommand(
        user=user,
        velocity_mps=velocity,
        direction=direction,
        ttl_s=DEFAULT_MANUAL_TTL_S if ttl is None else ttl,
        force=force,
    )


def stop_request_from(data: bytes) -> StopRequest:
    """What a stop keeps of its body, whatever the body is: never an error.

    A stop is refused only for its token (DESIGN §8): a reason too long is cut to
    :data:`MAX_REASON_CHARS`, one that is not a string is kept as its JSON text, unknown
    fields and a body that is not a JSON object are ignored — and the answer names each.
    """
    if not data.strip():
        return StopRequest(user=None, reason=None)
    try:
        raw = json.loads(data.decode("utf-8", "replace"))
    except (ValueError, RecursionError):
        raw = None
    if not isinstance(raw, Mapping):
        return StopRequest(user=None, reason=None, ignored=("body",))
    truncated: list[str] = []
    kept: dict[str, str | None] = {}
    for name, max_chars in (("user", MAX_USER_CHARS), ("reason", MAX_REASON_CHARS)):
        text = _any_text(raw.get(name))
        if text is not None and len(text) > max_chars:
            text = text[:max_chars].rstrip()
            truncated.append(name)
        kept[name] = text or None
    ignored = tuple(sorted((str(k) for k in set(raw) - STOP_FIELDS), key=str))
    return StopRequest(
        user=kept["user"], reason=kept["reason"], truncated=tuple(truncated), ignored=ignored
    )


def _any_text(value: object) -> str | None:
    """A field of a stop as text: a string as it is (stripped), anything else as its JSON;
    characters that cannot be stored as UTF-8 (lone surrogates) become U+FFFD."""
    if value is None:
        return None
    text = value if isinstance(value, str) else json.dumps(value, ensure_ascii=False)
    return _LONE_SURROGATE.sub("\ufffd", text).strip()


def parse_stop_body(raw: object, *, allowed: frozenset[str] = RELEASE_FIELDS) -> StopRequest:
    """The release's optional body, checked strictly (a release is not a stop): ``None``
    (no body) is an empty request."""
    if raw is None:
        return StopRequest(user=None, reason=None)
    errors: FieldErrors = {}
    if not isinstance(raw, Mapping):
        raise InvalidRunBody({"body": ["must be a JSON object"]})
    _unknown(raw, allowed, errors)
    user = _text(raw, "user", MAX_USER_CHARS, errors, required=False)
    reason = _text(raw, "reason", MAX_REASON_CHARS, errors, required=False)
    if errors:
        raise InvalidRunBody(errors)
    return StopRequest(user=user, reason=reason)


def _add(errors: FieldErrors, field: str, message: str) -> None:
    errors.setdefault(field, []).append(message)


def _unknown(raw: Mapping[Any, Any], allowed: frozenset[str], errors: FieldErrors) -> None:
    for name in sorted(set(raw) - allowed, key=str):
        _add(errors, str(name), "unknown field")


def _text(
    raw: Mapping[Any, Any], name: str, max_chars: int, errors: FieldErrors, *, required: bool
) -> str | None:
    if name not in raw:
        if required:
            _add(errors, name, "is required")
        return None
    value = raw[name]
    if not isinstance(value, str):
        _add(errors, name, "must be a string")
        return None
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        _add(errors, name, "must be a string")
        return None
    if not value.strip():
        _add(errors, name, "must not be blank")
        return None
    if len(value) > max_chars:
        _add(errors, name, f"must be at most {max_chars} characters")
        return None
    return value.strip()
