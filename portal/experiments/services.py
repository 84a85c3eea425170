"""Writes for experiments: the programs a mobile node runs, validated before they are kept."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from basestation.contract import (
    DIRECTIONS,
    MAX_PROGRAM_S,
    MAX_SEGMENTS,
    MAX_TITLE_CHARS,
    SEGMENT_FIELDS,
)
from bookings.models import Resource
from bookings.rules import velocity_problem
from bookings.selectors import fastest_mobile
from portal.accounts.models import User
from portal.errors import InvalidInput
from portal.experiments.models import Experiment


def segments_validate(segments: Any, *, robot: Resource | None) -> list[dict[str, Any]]:
    """A clean copy of a program, or ``InvalidInput`` naming the segment and field at fault.

    Velocities are checked against ``robot`` (``bookings.rules.velocity_problem``, the
    portal's one velocity check); with no robot, only that they are numbers ≥ 0.
    """
    if not isinstance(segments, list) or not segments:
        raise InvalidInput.on_field("segments", "An experiment needs at least one segment.")
    if len(segments) > MAX_SEGMENTS:
        raise InvalidInput.on_field("segments", f"At most {MAX_SEGMENTS} segments.")
    keys = set(SEGMENT_FIELDS)
    errors: list[str] = []
    clean: list[dict[str, Any]] = []
    for i, raw in enumerate(segments, start=1):
        if not isinstance(raw, Mapping):
            errors.append(f"Segment {i}: must be an object with {sorted(keys)}.")
            continue
        unknown = set(raw) - keys
        missing = keys - set(raw)
        if unknown or missing:
            parts = []
            if missing:
                parts.append(f"missing {', '.join(sorted(missing))}")
            if unknown:
                parts.append(f"unknown {', '.join(sorted(unknown))}")
            errors.append(f"Segment {i}: {'; '.join(parts)}.")
            continue
        velocity = _number(raw["velocity_mps"])
        duration = _number(raw["duration_s"])
        direction = raw["direction"]
        if velocity is None or velocity < 0:
            errors.append(f"Segment {i}: velocity must be a number ≥ 0 m/s.")
        elif robot is not None:
            why = velocity_problem(resource=robot, velocity_mps=velocity)
            if why is not None:
                errors.append(f"Segment {i}: {why}")
        if direction not in DIRECTIONS:
            errors.append(f"Segment {i}: direction must be 'cw' or 'ccw'.")
        if duration is None or duration <= 0:
            errors.append(f"Segment {i}: duration must be a number > 0 s.")
        if not errors:
            clean.append({"velocity_mps": velocity, "direction": direction, "duration_s": duration})
    if errors:
        raise InvalidInput(errors[0], fields={"segments": errors})
    total_s = sum(s["duration_s"] for s in clean)
    if total_s > MAX_PROGRAM_S:
        raise InvalidInput.on_field(
            "segments", f"The program lasts {total_s:g} s; at most {MAX_PROGRAM_S:g} s."
        )
    return clean


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        return None
    try:
        number = float(value)
    except ValueError:
        return None
    return number if math.isfinite(number) else None


def _title_validate(title: Any) -> str:
    if not isinstance(title, str) or not title.strip():
        raise InvalidInput.on_field("title", "A title is required.")
    if len(title) > MAX_TITLE_CHARS:
        raise InvalidInput.on_field("title", f"At most {MAX_TITLE_CHARS} characters.")
    return title.strip()


def experiment_create(*, owner: User, title: str, segments: Any) -> Experiment:
    """A new program, its velocities checked against the fastest robot (booking checks
    them again against the robot it books)."""
    experiment = Experiment(
        owner=owner,
        title=_title_validate(title),
        segments=segments_validate(segments, robot=fastest_mobile()),
    )
    experiment.full_clean()
    experiment.save()
    return experiment


def experiment_update(*, experiment: Experiment, title: str, segments: Any) -> Experiment:
    experiment.title = _title_validate(title)
    experiment.segments = segments_validate(segments, robot=fastest_mobile())
    experiment.full_clean()
    experiment.save()
    return experiment
