"""A campaign's file read and expanded into its runs: plain functions, without the database.

A campaign sweeps a one-segment program over its parameters' values (each a list, or a range
``{from, to, step}``), every combination ``repeats`` times, in the order listed (each repeat
after the last: a whole sweep, then the next) or shuffled with a seed. Anything unknown, out of
range or too many is refused with the field it concerns.
"""

from __future__ import annotations

import itertools
import math
import random
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from basestation.contract import DIRECTIONS, MAX_PROGRAM_S
from core.errors import InvalidInput

# The most runs one campaign may queue.
CAMPAIGN_RUNS_MAX = 200
# The most values a range may give (a step too small for its span is a mistake).
RANGE_VALUES_MAX = 100
PARAMETERS = ("velocity_mps", "direction", "duration_s")
FIELDS = frozenset(
    {
        "title",
        "robot",
        "parameters",
        "repeats",
        "order",
        "seed",
        "earliest_at",
        "latest_end_at",
        "hours",
        "nodes",
    }
)
ORDERS = ("listed", "random")


@dataclass(frozen=True)
class SweepRun:
    """One run of a campaign: its parameters' values and which repeat it is (1 on)."""

    velocity_mps: float
    direction: str
    duration_s: float
    repeat: int

    @property
    def parameters(self) -> dict[str, Any]:
        return {
            "velocity_mps": self.velocity_mps,
            "direction": self.direction,
            "duration_s": self.duration_s,
            "repeat": self.repeat,
        }

    @property
    def segments(self) -> list[dict[str, Any]]:
        return [
            {
                "velocity_mps": self.velocity_mps,
                "direction": self.direction,
                "duration_s": self.duration_s,
            }
        ]


@dataclass(frozen=True)
class Sweep:
    title: str
    robot: str
    nodes: tuple[str, ...]
    velocities_mps: tuple[float, ...]
    directions: tuple[str, ...]
    durations_s: tuple[float, ...]
    repeats: int
    order: str
    seed: int | None
    earliest_at: datetime | None
    latest_end_at: datetime
    hours: tuple[int, int] | None

    def runs(self) -> list[SweepRun]:
        combos = list(itertools.product(self.velocities_mps, self.directions, self.durations_s))
        runs = [
            SweepRun(v, d, t, repeat) for repeat in range(1, self.repeats + 1) for v, d, t in combos
        ]
        if self.order == "random":
            random.Random(self.seed).shuffle(runs)
        return runs


def _refuse(field: str, message: str) -> InvalidInput:
    return InvalidInput(f"{field}: {message}", fields={field: [message]})


def _number(field: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise _refuse(field, f"{value!r} is not a number.")
    return float(value)


def _values(field: str, raw: Any) -> list[Any]:
    """A parameter's values: a list, one value, or a range ``{from, to, step}`` (both ends
    included when the steps land on ``to``)."""
    if isinstance(raw, dict):
        unknown = sorted(set(raw) - {"from", "to", "step"})
        if unknown or {"from", "to", "step"} - set(raw):
            raise _refuse(field, "A range is {from, to, step}, and nothing else.")
        lo, hi = _number(field, raw["from"]), _number(field, raw["to"])
        step = _number(field, raw["step"])
        if step <= 0 or hi < lo:
            raise _refuse(
                field, "A range runs from a value up to a larger one, by a positive step."
            )
        count = math.floor((hi - lo) / step + 1e-9) + 1
        if count > RANGE_VALUES_MAX:
            raise _refuse(field, f"A range gives at most {RANGE_VALUES_MAX} values ({count} here).")
        return [round(lo + i * step, 9) for i in range(count)]
    values = raw if isinstance(raw, list) else [raw]
    if not values:
        raise _refuse(field, "Give at least one value.")
    return values


def _parameters(parameters: Any) -> tuple[list[float], list[str], list[float]]:
    """The swept values of each parameter, checked."""
    if not isinstance(parameters, dict):
        raise _refuse("parameters", "A mapping of parameter names to values.")
    unknown = sorted(set(parameters) - set(PARAMETERS))
    if unknown:
        raise _refuse(
            "parameters",
            f"Unknown parameter(s): {', '.join(unknown)}; known: {', '.join(PARAMETERS)}.",
        )
    missing = [name for name in PARAMETERS if name not in parameters]
    if missing:
        raise _refuse("parameters", f"Give values for {', '.join(missing)}.")
    velocities = [
        _number("velocity_mps", v) for v in _values("velocity_mps", parameters["velocity_mps"])
    ]
    if any(v < 0 for v in velocities):
        raise _refuse(
            "velocity_mps", "A velocity is at least 0 m/s (the direction says which way)."
        )
    directions = _values("direction", parameters["direction"])
    if any(d not in DIRECTIONS for d in directions):
        raise _refuse("direction", f"A direction is one of {', '.join(DIRECTIONS)}.")
    durations = [_number("duration_s", t) for t in _values("duration_s", parameters["duration_s"])]
    if any(not 0 < t <= MAX_PROGRAM_S for t in durations):
        raise _refuse("duration_s", f"A duration lies in (0, {MAX_PROGRAM_S:g}] s.")
    return velocities, directions, durations


def _repeats_order_seed_hours(spec: dict[str, Any]) -> tuple[int, str, int | None, Any]:
    repeats = spec.get("repeats", 1)
    if isinstance(repeats, bool) or not isinstance(repeats, int) or not 1 <= repeats <= 100:
        raise _refuse("repeats", "Repeats are a whole number from 1 to 100.")
    order = spec.get("order", "listed")
    if order not in ORDERS:
        raise _refuse("order", f"The order is one of {', '.join(ORDERS)}.")
    seed = spec.get("seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
        raise _refuse("seed", "A seed is a whole number.")
    hours = spec.get("hours")
    if hours is not None and (
        not isinstance(hours, list)
        or len(hours) != 2
        or not all(isinstance(h, int) and not isinstance(h, bool) for h in hours)
    ):
        raise _refuse("hours", "Allowed hours are [from, to], such as [22, 6].")
    return repeats, order, seed, hours


def sweep_parse(spec: Any, *, parse_time: Any) -> Sweep:
    """The campaign file (already read from YAML or JSON) as a :class:`Sweep`, or the first
    thing wrong with it. ``parse_time`` reads an instant (the API's own reading)."""
    if not isinstance(spec, dict):
        raise InvalidInput("A campaign is a mapping of its fields.")
    unknown = sorted(set(spec) - FIELDS)
    if unknown:
        raise _refuse(
            unknown[0],
            f"Unknown field(s): {', '.join(unknown)}; known: {', '.join(sorted(FIELDS))}.",
        )
    for required in ("title", "robot", "parameters", "latest_end_at"):
        if required not in spec:
            raise _refuse(required, "This field is required.")
    title = spec["title"]
    if not isinstance(title, str) or not title.strip() or len(title) > 150:
        raise _refuse("title", "A title of 1 to 150 characters.")
    robot = spec["robot"]
    if not isinstance(robot, str):
        raise _refuse("robot", "The robot's name.")
    nodes = spec.get("nodes", [])
    if not isinstance(nodes, list) or not all(isinstance(n, str) for n in nodes):
        raise _refuse("nodes", "A list of fixed nodes' names.")
    velocities, directions, durations = _parameters(spec["parameters"])
    repeats, order, seed, hours = _repeats_order_seed_hours(spec)
    sweep = Sweep(
        title=title.strip(),
        robot=robot,
        nodes=tuple(nodes),
        velocities_mps=tuple(velocities),
        directions=tuple(directions),
        durations_s=tuple(durations),
        repeats=repeats,
        order=order,
        seed=seed,
        earliest_at=parse_time("earliest_at", spec["earliest_at"])
        if "earliest_at" in spec
        else None,
        latest_end_at=parse_time("latest_end_at", spec["latest_end_at"]),
        hours=(hours[0], hours[1]) if hours is not None else None,
    )
    count = len(velocities) * len(directions) * len(durations) * repeats
    if count > CAMPAIGN_RUNS_MAX:
        raise _refuse(
            "parameters",
            f"This campaign would queue {count} runs; at most {CAMPAIGN_RUNS_MAX}.",
        )
    return sweep
