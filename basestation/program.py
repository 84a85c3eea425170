"""A run's body: parsing, validation, canonical form, and where the program is at a time.

A body is checked in two steps. :func:`parse_run_body` checks what the body says about
itself (types, formats, ranges, end after start, program fits the window); its result has a
canonical JSON form, so "is this the same body?" compares meaning, not bytes.
:func:`check_run_admissible` then checks the body against this agent and this moment (the
agent's velocity limit, end not in the past). The split lets an identical re-PUT of a run
that has already started or ended still answer 200.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from basestation.contract import (
    DIRECTIONS,
    MAX_OWNER_CHARS,
    MAX_SEGMENTS,
    MAX_TITLE_CHARS,
    SEGMENT_FIELDS,
    Direction,
)

BODY_FIELDS = frozenset({"owner", "title", "start_at", "end_at", "segments", "limits"})
LIMIT_FIELDS = frozenset({"max_velocity_mps", "max_accel_mps2"})

FieldErrors = dict[str, list[str]]


class InvalidRunBody(Exception):
    """The body cannot be staged; ``fields`` maps each offending field to its messages."""

    def __init__(self, fields: FieldErrors) -> None:
        super().__init__("invalid run body: " + "; ".join(sorted(fields)))
        self.fields = fields


@dataclass(frozen=True)
class Segment:
    velocity_mps: float
    direction: Direction
    duration_s: float


@dataclass(frozen=True)
class RunLimits:
    max_velocity_mps: float
    max_accel_mps2: float


@dataclass(frozen=True)
class RunSpec:
    owner: str
    title: str
    start_at: datetime  # aware, UTC
    end_at: datetime  # aware, UTC
    segments: tuple[Segment, ...]
    limits: RunLimits

    @property
    def start_at_s(self) -> float:
        return self.start_at.timestamp()

    @property
    def end_at_s(self) -> float:
        return self.end_at.timestamp()

    @property
    def program_duration_s(self) -> float:
        return math.fsum(s.duration_s for s in self.segments)

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "owner": self.owner,
            "title": self.title,
            "start_at": format_time(self.start_at),
            "end_at": format_time(self.end_at),
            "segments": [
                {
                    "velocity_mps": s.velocity_mps,
                    "direction": s.direction,
                    "duration_s": s.duration_s,
                }
                for s in self.segments
            ],
            "limits": {
                "max_velocity_mps": self.limits.max_velocity_mps,
                "max_accel_mps2": self.limits.max_accel_mps2,
            },
        }

    def canonical_json(self) -> str:
        """One text per meaning: UTC times at microsecond precision, floats, sorted keys."""
        return json.dumps(
            self.to_json_dict(), sort_keys=True, separators=(",", ":"), allow_nan=False
        )

    @classmethod
    def from_canonical_json(cls, text: str) -> RunSpec:
        return parse_run_body(json.loads(text))

    def program_at(self, now_s: float) -> tuple[int | None, float, Direction]:
        """The segment index, commanded speed and direction at agent time ``now_s``.

        Segment k runs for its duration counted from ``start_at``; before the start and
        after the last segment the command is speed 0 (index None). The direction after
        the program is the last segment's, so the robot is not told to turn round while
        it brakes.
        """
        elapsed_s = now_s - self.start_at_s
        if elapsed_s < 0:
            return None, 0.0, self.segments[0].direction
        boundary_s = 0.0
        for index, segment in enumerate(self.segments):
            boundary_s += segment.duration_s
            if elapsed_s < boundary_s:
                return index, segment.velocity_mps, segment.direction
        return None, 0.0, self.segments[-1].direction


def format_time(value: datetime) -> str:
    """ISO-8601 in UTC with a ``Z``, microsecond precision (what the API returns)."""
    return value.astimezone(UTC).isoformat(timespec="microseconds").replace("+00:00", "Z")


def format_epoch(value_s: float | None) -> str | None:
    if value_s is None:
        return None
    return format_time(datetime.fromtimestamp(value_s, tz=UTC))


def parse_run_body(raw: object) -> RunSpec:
    """Check a decoded JSON body on its own terms; raise :class:`InvalidRunBody`."""
    errors: FieldErrors = {}
    if not isinstance(raw, Mapping):
        raise InvalidRunBody({"body": ["must be a JSON object"]})
    for name in sorted(set(raw) - BODY_FIELDS, key=str):
        _add(errors, str(name), "unknown field")

    owner = _text(raw, "owner", MAX_OWNER_CHARS, errors)
    title = _text(raw, "title", MAX_TITLE_CHARS, errors)
    start_at = _time(raw, "start_at", errors)
    end_at = _time(raw, "end_at", errors)
    limits = _limits(raw, errors)
    segments = _segments(raw, limits, errors)

    if start_at is not None and end_at is not None:
        if end_at <= start_at:
            _add(errors, "end_at", "must be after start_at")
        elif segments is not None:
            window_s = (end_at - start_at).total_seconds()
            # Plain sum: huge durations must give inf here, not fsum's OverflowError.
            program_s = sum(s.duration_s for s in segments)
            if program_s > window_s:
                _add(
                    errors,
                    "segments",
                    f"the program lasts {program_s:g} s, longer than the "
                    f"{window_s:g} s between start_at and end_at",
                )

    if errors:
        raise InvalidRunBody(errors)
    # No errors means every part parsed.
    assert owner is not None
    assert title is not None
    assert start_at is not None
    assert end_at is not None
    assert segments is not None
    assert limits is not None
    return RunSpec(
        owner=owner,
        title=title,
        start_at=start_at,
        end_at=end_at,
        segments=tuple(segments),
        limits=limits,
    )


def check_run_admissible(spec: RunSpec, *, max_velocity_mps: float, now_s: float) -> None:
    """Check a parsed body against this agent's limits and clock."""
    errors: FieldErrors = {}
    if spec.end_at_s <= now_s:
        _add(errors, "end_at", "is in the past")
    for index, segment in enumerate(spec.segments):
        if segment.velocity_mps > max_velocity_mps:
            _add(
                errors,
                f"segments[{index}].velocity_mps",
                f"{segment.velocity_mps:g} m/s is above this robot's maximum "
                f"{max_velocity_mps:g} m/s",
            )
    if errors:
        raise InvalidRunBody(errors)


def _add(errors: FieldErrors, field: str, message: str) -> None:
    errors.setdefault(field, []).append(message)


def _is_text(value: object) -> bool:
    if not isinstance(value, str):
        return False
    try:
        # JSON can carry lone surrogates, which no database or CSV can store.
        value.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _text(raw: Mapping[Any, Any], name: str, max_chars: int, errors: FieldErrors) -> str | None:
    if name not in raw:
        _add(errors, name, "is required")
        return None
    value = raw[name]
    if not _is_text(value):
        _add(errors, name, "must be a string")
        return None
    assert isinstance(value, str)
    if not value.strip():
        _add(errors, name, "must not be blank")
        return None
    if len(value) > max_chars:
        _add(errors, name, f"must be at most {max_chars} characters")
        return None
    return value


def _time(raw: Mapping[Any, Any], name: str, errors: FieldErrors) -> datetime | None:
    if name not in raw:
        _add(errors, name, "is required")
        return None
    value = raw[name]
    if not _is_text(value):
        _add(errors, name, "must be an ISO-8601 date-time string with a timezone")
        return None
    try:
        parsed = datetime.fromisoformat(value)
    except ValueError:
        _add(errors, name, "must be an ISO-8601 date-time string with a timezone")
        return None
    if parsed.tzinfo is None or parsed.utcoffset() is None:
        _add(errors, name, "must include a timezone (e.g. 'Z' or '+01:00')")
        return None
    try:
        return parsed.astimezone(UTC)
    except (OverflowError, ValueError):
        _add(errors, name, "is out of range")
        return None


def parse_number(
    raw: Mapping[Any, Any],
    name: str,
    errors: FieldErrors,
    *,
    field: str | None = None,
    positive: bool = False,
    required: bool = True,
) -> float | None:
    """``raw[name]`` as a finite float, or None with the fault added to ``errors[field]``."""
    field = field or name
    if name not in raw:
        if required:
            _add(errors, field, "is required")
        return None
    value = raw[name]
    # bool is an int in Python, but true is not a velocity.
    if isinstance(value, bool) or not isinstance(value, int | float):
        _add(errors, field, "must be a number")
        return None
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        _add(errors, field, "must be a finite number")
        return None
    if positive and number <= 0:
        _add(errors, field, "must be greater than 0")
        return None
    if not positive and number < 0:
        _add(errors, field, "must not be negative")
        return None
    return number


def _limits(raw: Mapping[Any, Any], errors: FieldErrors) -> RunLimits | None:
    if "limits" not in raw:
        _add(errors, "limits", "is required")
        return None
    value = raw["limits"]
    if not isinstance(value, Mapping):
        _add(errors, "limits", "must be an object")
        return None
    for name in sorted(set(value) - LIMIT_FIELDS, key=str):
        _add(errors, f"limits.{name}", "unknown field")
    velocity = parse_number(
        value, "max_velocity_mps", errors, field="limits.max_velocity_mps", positive=True
    )
    accel = parse_number(
        value, "max_accel_mps2", errors, field="limits.max_accel_mps2", positive=True
    )
    if velocity is None or accel is None:
        return None
    return RunLimits(max_velocity_mps=velocity, max_accel_mps2=accel)


def _segments(
    raw: Mapping[Any, Any], limits: RunLimits | None, errors: FieldErrors
) -> list[Segment] | None:
    if "segments" not in raw:
        _add(errors, "segments", "is required")
        return None
    value = raw["segments"]
    if not isinstance(value, list):
        _add(errors, "segments", "must be a list")
        return None
    if not 1 <= len(value) <= MAX_SEGMENTS:
        _add(errors, "segments", f"must hold 1 to {MAX_SEGMENTS} segments")
        return None
    segments: list[Segment] = []
    valid = True
    for index, item in enumerate(value):
        prefix = f"segments[{index}]"
        if not isinstance(item, Mapping):
            _add(errors, prefix, "must be an object")
            valid = False
            continue
        for name in sorted(set(item) - set(SEGMENT_FIELDS), key=str):
            _add(errors, f"{prefix}.{name}", "unknown field")
            valid = False
        velocity = parse_number(item, "velocity_mps", errors, field=f"{prefix}.velocity_mps")
        if velocity is not None and limits is not None and velocity > limits.max_velocity_mps:
            _add(
                errors,
                f"{prefix}.velocity_mps",
                f"{velocity:g} m/s is above the run's max_velocity_mps {limits.max_velocity_mps:g}",
            )
            velocity = None
        duration = parse_number(
            item, "duration_s", errors, field=f"{prefix}.duration_s", positive=True
        )
        direction = item.get("direction")
        if "direction" not in item:
            _add(errors, f"{prefix}.direction", "is required")
            direction = None
        elif direction not in DIRECTIONS:
            _add(errors, f"{prefix}.direction", "must be 'cw' or 'ccw'")
            direction = None
        if velocity is None or duration is None or direction is None:
            valid = False
            continue
        segments.append(Segment(velocity_mps=velocity, direction=direction, duration_s=duration))
    return segments if valid else None
