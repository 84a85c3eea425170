"""Laps and passes from the along-track position.

``track_m`` wraps at the rail length, so it jumps from ``length_m`` to 0 (clockwise) or
from 0 to ``length_m`` (counter-clockwise) at the origin. Unwrapping takes the shorter way
round between consecutive samples: at 20 Hz and a few m/s the robot moves centimetres per
sample, never half a rail, so the shorter way is the way the robot went.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

PassDirection = Literal["cw", "ccw"]


def wrap_delta_m(delta_m: float, length_m: float) -> float:
    """``delta_m`` moved into ``[-length_m / 2, length_m / 2)``: the shorter way round."""
    half_m = length_m / 2.0
    return (delta_m + half_m) % length_m - half_m


def unwrap_track(track_m: Iterable[float], length_m: float) -> list[float]:
    """Continuous positions from wrapped ones: the first value is kept, every step after it
    is the shorter way round the rail."""
    _check_length(length_m)
    unwrapped: list[float] = []
    previous_m: float | None = None
    for value_m in track_m:
        if previous_m is None:
            unwrapped.append(value_m)
        else:
            unwrapped.append(unwrapped[-1] + wrap_delta_m(value_m - previous_m, length_m))
        previous_m = value_m
    return unwrapped


@dataclass(frozen=True)
class Pass:
    """The robot crossed the chosen position."""

    index: int  # 1, 2, 3, … in order of time
    t_s: float  # interpolated between the two samples either side of the crossing
    direction: PassDirection
    velocity_mps: float  # speed at the crossing, never negative


class LapCounter:
    """Follows ``track_m`` sample by sample: unwrapped position, laps, and passes at
    ``pass_at_m``.

    ``laps`` is the number of whole laps of net progress since the first sample, positive
    clockwise and negative counter-clockwise; ``laps_travelled`` counts whole laps of path
    whatever the direction (a robot going 1.5 laps cw and back 1.5 ccw has 0 and 3).

    ``distance_m``, the path travelled, is the speed the robot reports integrated over time
    (each sample's speed held until the next), not the position's changes summed: the GPS's
    position jitters by centimetres at every fix, which summed would make a robot standing
    still travel metres. The reported speed is the firmware's ramp, within half a duty step
    (16 mm/s) of the true one (docs/simulator.md). Samples given without a speed fall back to
    the position's change.
    """

    def __init__(self, length_m: float, *, pass_at_m: float | None = None) -> None:
        _check_length(length_m)
        if pass_at_m is not None and not math.isfinite(pass_at_m):
            raise ValueError(f"pass_at_m must be a finite number, got {pass_at_m!r}")
        self.length_m = length_m
        self.pass_at_m = None if pass_at_m is None else pass_at_m % length_m
        self.start_m: float | None = None
        self.unwrapped_m: float | None = None
        self.distance_m = 0.0
        self.passes: list[Pass] = []
        self._last_track_m = 0.0
        self._last_t_s = 0.0
        self._last_velocity_mps: float | None = None

    @property
    def net_m(self) -> float:
        """Net progress since the first sample, clockwise positive."""
        if self.start_m is None or self.unwrapped_m is None:
            return 0.0
        return self.unwrapped_m - self.start_m

    @property
    def laps(self) -> int:
        return int(self.net_m / self.length_m)  # truncated: a lap counts once complete

    @property
    def laps_travelled(self) -> int:
        return int(self.distance_m // self.length_m)

    def update(self, track_m: float, t_s: float, velocity_mps: float | None = None) -> list[Pass]:
        """Take one sample; return the passes it completed (at most one per sample)."""
        if not math.isfinite(track_m) or not math.isfinite(t_s):
            raise ValueError(f"track_m and t_s must be finite, got {track_m!r}, {t_s!r}")
        track_m %= self.length_m
        if self.unwrapped_m is None:
            self.start_m = self.unwrapped_m = track_m
            self._remember(track_m, t_s, velocity_mps)
            return []
        before_m = self.unwrapped_m
        after_m = before_m + wrap_delta_m(track_m - self._last_track_m, self.length_m)
        self.unwrapped_m = after_m
        if velocity_mps is not None and self._last_velocity_mps is not None:
            self.distance_m += abs(self._last_velocity_mps) * max(0.0, t_s - self._last_t_s)
        else:
            self.distance_m += abs(after_m - before_m)
        new_passes = self._passes_between(before_m, after_m, t_s, velocity_mps)
        self._remember(track_m, t_s, velocity_mps)
        return new_passes

    def _remember(self, track_m: float, t_s: float, velocity_mps: float | None) -> None:
        self._last_track_m = track_m
        self._last_t_s = t_s
        self._last_velocity_mps = velocity_mps

    def _passes_between(
        self, before_m: float, after_m: float, t_s: float, velocity_mps: float | None
    ) -> list[Pass]:
        if self.pass_at_m is None or after_m == before_m:
            return []
        # The rail is cut into cells [pass_at + kL, pass_at + (k+1)L): changing cell is
        # crossing the position. A step is under half a rail, so at most one crossing.
        cell_before = math.floor((before_m - self.pass_at_m) / self.length_m)
        cell_after = math.floor((after_m - self.pass_at_m) / self.length_m)
        if cell_before == cell_after:
            return []
        clockwise = after_m > before_m
        crossing_m = self.pass_at_m + self.length_m * (cell_after if clockwise else cell_before)
        fraction = (crossing_m - before_m) / (after_m - before_m)
        dt_s = t_s - self._last_t_s
        if velocity_mps is not None and self._last_velocity_mps is not None:
            speed_mps = self._last_velocity_mps + fraction * (
                velocity_mps - self._last_velocity_mps
            )
        elif dt_s > 0:
            speed_mps = abs(after_m - before_m) / dt_s
        else:
            speed_mps = velocity_mps or 0.0
        found = Pass(
            index=len(self.passes) + 1,
            t_s=self._last_t_s + fraction * dt_s,
            direction="cw" if clockwise else "ccw",
            velocity_mps=abs(speed_mps),
        )
        self.passes.append(found)
        return [found]


def _check_length(length_m: float) -> None:
    if not math.isfinite(length_m) or length_m <= 0:
        raise ValueError(f"length_m must be a positive number, got {length_m!r}")
