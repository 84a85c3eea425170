"""Bodies of the admin operations: manual drive (``POST /control``) and the e-stop.

Parsed like run bodies: every problem is collected into field errors
(:class:`~basestation.program.InvalidRunBody`, answered 422), unknown fields are refused.
"""

from __future__ import annotations

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
MAX_REASON_CHARS = 200

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


def parse_stop_body(raw: object, *, allowed: frozenset[str] = STOP_FIELDS) -> StopRequest:
    """An optional body: ``None`` (no body) is an empty request."""
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
