"""Writes for experiments: the programs a mobile node runs, validated before they are kept."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from basestation.contract import (
    DIRECTIONS,
    MAX_PROGRAM_S,
    MAX_SEGMENTS,
    MAX_TITLE_CHARS,
    SEGMENT_FIELDS,
)
from bookings.models import Resource
from bookings.rules import FIRST_SEGMENT, robots_fitting
from bookings.selectors import mobiles_bookable
from core.accounts.models import User
from core.errors import InvalidInput
from portal.experiments.models import Experiment


def segments_validate(segments: Any, *, robots: Sequence[Resource] = ()) -> list[dict[str, Any]]:
    """A clean copy of a program, or ``InvalidInput`` naming the segment and field at fault.

    With ``robots`` (the ones the author may book), the program must fit at least one of
    them (``bookings.rules.robots_fitting``: each robot's stricter of the portal's and its
    agent's limit); a segment faster than all of them is refused, naming each limit. With no
    robot, velocities need only be numbers ≥ 0.
    """
    if not isinstance(segments, list) or not segments:
        raise InvalidInput.on_field("segments", "An experiment needs at least one segment.")
    if len(segments) > MAX_SEGMENTS:
        raise InvalidInput.on_field("segments", f"At most {MAX_SEGMENTS} segments.")
    keys = set(SEGMENT_FIELDS)
    errors: list[str] = []
    clean: list[dict[str, Any]] = []
    for i, raw in enumerate(segments, start=FIRST_SEGMENT):
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
        if direction not in DIRECTIONS:
            errors.append(f"Segment {i}: direction must be 'cw' or 'ccw'.")
        if duration is None or duration <= 0:
            errors.append(f"Segment {i}: duration must be a number > 0 s.")
        if not errors:
            clean.append({"velocity_mps": velocity, "direction": direction, "duration_s": duration})
    if not errors:
        errors = _too_fast(clean, robots)
    if errors:
        raise InvalidInput(errors[0], fields={"segments": errors})
    total_s = sum(s["duration_s"] for s in clean)
    if total_s > MAX_PROGRAM_S:
        raise InvalidInput.on_field(
            "segments", f"The program lasts {total_s:g} s; at most {MAX_PROGRAM_S:g} s."
        )
    return clean


def _too_fast(clean: list[dict[str, Any]], robots: Sequence[Resource]) -> list[str]:
    """A message per segment faster than every robot, when the program fits none."""
    fits = robots_fitting(robots, [s["velocity_mps"] for s in clean])
    if not fits or any(fit.fits for fit in fits):
        return []
    fastest_mps = max(fit.limit.mps for fit in fits)
    limits = "; ".join(f"{fit.limit.resource}: {fit.limit.describe()}" for fit in fits)
    return [
        f"Segment {i}: velocity {s['velocity_mps']:g} m/s is faster than every robot you may "
        f"book ({limits})."
        for i, s in enumerate(clean, start=FIRST_SEGMENT)
        if s["velocity_mps"] > fastest_mps
    ]


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
    """A new program that fits at least one robot its author may book (booking checks it
    again against the robot it books)."""
    experiment = Experiment(
        owner=owner,
        title=_title_validate(title),
        segments=segments_validate(segments, robots=mobiles_bookable()),
    )
    experiment.full_clean()
    experiment.save()
    return experiment


def experiment_update(*, experiment: Experiment, title: str, segments: Any) -> Experiment:
    experiment.title = _title_validate(title)
    experiment.segments = segments_validate(segments, robots=mobiles_bookable())
    experiment.full_clean()
    experiment.save()
    return experiment
