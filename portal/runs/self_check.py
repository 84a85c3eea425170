"""The robot's self-check: its standard program, and what its samples say of the robot.

The program (:func:`self_check_program`) steps the velocity up in both directions, rests
after each step, and drives one full lap. From the samples (:func:`self_check_figures`),
measured against the robot's position as its GPS saw it (the along-track ``track_m``, not
the firmware's own speed, which without a wheel sensor is only its ramp), come the numbers
of the thesis's chapter 4:

- ``tracking_error_mps``: how far the ground speed stays from the command once settled, the
  worst step (a slipping wheel or a weak motor holds the robot below it);
- ``accel_mps2``: the ground speed's rise between 20 % and 80 % of a step, the weakest step
  (the base station ramps the command at the robot's acceleration limit);
- ``lag_s``: how long the ground speed trails that ramp at half the step (a lagging motor
  controller or throttle filter);
- ``stop_distance_m`` and ``stop_time_s``: from the command's drop to 0 after the fastest
  clockwise step to the robot standing still;
- ``battery_sag_v``: the battery at rest minus its lowest reading while accelerating (a
  battery with a high internal resistance sags under the motor's current);
- ``rtk_share``: the share of the lap's samples with an RTK-fixed position (the GPS losing its
  fix near a wall, or its corrections);
- ``link_loss_share``: the share of the base station's commands the robot did not answer over
  the run, and ``cpu_temp_c``: the Pi's temperature as the run ended (both as the base station
  recorded them: the run's provenance).

Each figure is judged (:func:`self_check_judge`) against a limit that holds for any robot
(from its own configured acceleration) and against its baseline, the robot's own first
passing check or one an admin chose, within a tolerance. Pure functions over the samples'
columns: the same code judges a check on the roof, in the tests and on a dry run.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any, Final

import numpy as np

from portal.runs.analysis import RTK_FIXED, SampleColumns

# The program. Steps at half and at the full check speed, each direction; the check speed is
# the robot's limit, at most this (a check must not be the fastest the robot ever goes).
CHECK_VELOCITY_MAX_MPS: Final = 1.0
# Held this long at speed after the ramp, for the speed to settle and be measured.
STEADY_S: Final = 4.0
# Rest after a step: the ramp down, then this long standing still.
REST_S: Final = 3.0
# Rest before the first step: the battery's reading at rest.
FIRST_REST_S: Final = 3.0

# The analysis. The ground speed is the track's slope over this window (the GPS reports at
# 10 Hz; a wider window averages its noise, a narrower one follows the ramp more closely),
# fitted to at least this many RTK-fixed positions.
SPEED_WINDOW_S: Final = 1.0
MIN_FIXES_PER_WINDOW: Final = 5
# The acceleration: the ground speed's rise over this span around half the fastest step.
ACCEL_SPAN_S: Final = 1.0
# After the ramp, the ground speed settles (the motor's lag) before it is measured.
SETTLE_S: Final = 1.0
# Standing still: the ground speed under this.
STILL_MPS: Final = 0.05
# The battery's reading is median-filtered on the robot; its lowest is read over this window.
BATTERY_WINDOW_S: Final = 0.5


@dataclass(frozen=True)
class Step:
    segment: int
    velocity_mps: float  # signed: + = clockwise


@dataclass(frozen=True)
class Program:
    segments: list[dict[str, Any]]
    steps: list[Step]
    stop_segment: int  # the rest after the fastest clockwise step
    lap_segment: int
    check_velocity_mps: float
    accel_mps2: float
    lap_m: float


def self_check_program(*, max_velocity_mps: float, max_accel_mps2: float, lap_m: float) -> Program:
    """The check's segments for a robot with these limits, its lap ``lap_m`` long (the rail's
    length: one full lap)."""
    if max_velocity_mps <= 0 or max_accel_mps2 <= 0 or lap_m <= 0:
        raise ValueError("the robot's limits and the lap must be above 0")
    fast = min(CHECK_VELOCITY_MAX_MPS, max_velocity_mps)
    segments: list[dict[str, Any]] = [_segment(0.0, "cw", FIRST_REST_S)]
    steps: list[Step] = []
    stop_segment = 0
    for speed in (fast / 2, fast):
        ramp_s = speed / max_accel_mps2
        for direction in ("cw", "ccw"):
            steps.append(Step(len(segments), speed if direction == "cw" else -speed))
            segments.append(_segment(speed, direction, ramp_s + STEADY_S))
            if speed == fast and direction == "cw":
                stop_segment = len(segments)
            segments.append(_segment(0.0, direction, ramp_s + REST_S))
    # A full lap: the distance at speed plus what the ramp up loses (half its time).
    lap_segment = len(segments)
    ramp_s = fast / max_accel_mps2
    segments.append(_segment(fast, "cw", lap_m / fast + ramp_s / 2))
    segments.append(_segment(0.0, "cw", ramp_s + REST_S))
    return Program(segments, steps, stop_segment, lap_segment, fast, max_accel_mps2, lap_m)


def _segment(velocity_mps: float, direction: str, duration_s: float) -> dict[str, Any]:
    return {
        "velocity_mps": round(velocity_mps, 3),
        "direction": direction,
        "duration_s": round(duration_s, 2),
    }


@dataclass(frozen=True)
class Figures:
    """The check's figures; the motion's are None when the positions could not measure them
    (``unmeasured`` says why: without an RTK fix, centimetres become decimetres)."""

    rtk_share: float
    battery_sag_v: float
    link_loss_share: float | None = None
    cpu_temp_c: float | None = None
    tracking_error_mps: float | None = None
    accel_mps2: float | None = None
    lag_s: float | None = None
    stop_distance_m: float | None = None
    stop_time_s: float | None = None
    unmeasured: str = ""

    def as_dict(self) -> dict[str, float | None]:
        return {
            name: None if value is None else round(value, 4)
            for name, value in asdict(self).items()
            if name != "unmeasured"
        }


class NotMeasurable(ValueError):
    """The samples do not hold what a figure needs (a run cut short); says which."""


def self_check_figures(
    columns: SampleColumns,
    program: Program,
    *,
    rail_length_m: float,
    link_loss_pct: float | None = None,
    cpu_temp_c: float | None = None,
) -> Figures:
    """The check's figures from its run's samples, and what the base station recorded as the
    run ended (the link's loss over the run, the Pi's temperature; None: not recorded);
    :class:`NotMeasurable` for a run that did not reach the end of its program."""
    t = columns.t_s
    starts = _segment_starts(columns, len(program.segments))
    rest = columns.battery_v[columns.segment == 0]
    if not len(rest) or len(starts) <= len(program.segments):
        raise NotMeasurable("the run did not reach the end of its program")
    lap = columns.segment == program.lap_segment
    rest_v = float(np.median(rest))
    sags = [
        rest_v - _lowest_median(t, columns.battery_v, starts[s.segment], starts[s.segment + 1])
        for s in program.steps
    ]
    measured = Figures(
        rtk_share=float(np.mean(columns.fix_quality[lap] == RTK_FIXED)) if lap.any() else 0.0,
        battery_sag_v=max(0.0, max(sags)),
        link_loss_share=None if link_loss_pct is None else link_loss_pct / 100.0,
        cpu_temp_c=cpu_temp_c,
    )
    try:
        return _motion_figures(columns, program, starts, rail_length_m, measured)
    except NotMeasurable as exc:
        return replace(measured, unmeasured=str(exc))


def _motion_figures(
    columns: SampleColumns,
    program: Program,
    starts: list[float],
    rail_length_m: float,
    measured: Figures,
) -> Figures:
    t = columns.t_s
    track = GroundTrack.fit(t, _unwrapped(columns.track_m, rail_length_m), columns.fix_quality)
    errors, accels, lags = [], [], []
    for step in program.steps:
        v = step.velocity_mps
        t0 = starts[step.segment]
        ramp_s = abs(v) / program.accel_mps2
        along = track.speed_mps * math.copysign(1.0, v)  # the step's direction positive
        settled = track.known & (t >= t0 + ramp_s + SETTLE_S) & (t < starts[step.segment + 1])
        if not settled.any():
            raise NotMeasurable(f"no RTK-fixed position at speed in segment {step.segment}")
        errors.append(abs(float(np.mean(along[settled])) - abs(v)))
        t50 = _first_at_least(t, along, track.known, t0, 0.5 * abs(v))
        if abs(v) == program.check_velocity_mps:
            # Mid-ramp, where a whole window of speeds lies on the ramp (the slow step's
            # ramp is too short for that).
            accels.append(
                (track.speed_at(t50 + ACCEL_SPAN_S / 2) - track.speed_at(t50 - ACCEL_SPAN_S / 2))
                * math.copysign(1.0, v)
                / ACCEL_SPAN_S
            )
        lags.append(t50 - (t0 + ramp_s / 2))
    stop_at = starts[program.stop_segment]
    still_at = _still_from(t, track, stop_at)
    return replace(
        measured,
        tracking_error_mps=max(errors),
        accel_mps2=min(accels),
        lag_s=max(lags),
        stop_distance_m=abs(track.position_at(still_at) - track.position_at(stop_at)),
        stop_time_s=still_at - stop_at,
    )


@dataclass(frozen=True)
class GroundTrack:
    """The robot's ground speed and smoothed position at each sample: a straight line fitted
    by least squares to the RTK-fixed positions within SPEED_WINDOW_S around it (the GPS
    reports at 10 Hz with centimetre noise; a position without an RTK fix is too coarse for
    a speed). ``known`` is False where the window held too few fixed positions."""

    t_s: np.ndarray
    position_m: np.ndarray
    speed_mps: np.ndarray
    known: np.ndarray

    @classmethod
    def fit(cls, t: np.ndarray, x: np.ndarray, fix_quality: np.ndarray) -> GroundTrack:
        w = (fix_quality == RTK_FIXED).astype(np.float64)
        origin = t[0] if len(t) else 0.0
        tc = t - origin  # conditioning: sums of squares of small numbers

        def sums(values: np.ndarray) -> np.ndarray:
            return np.concatenate(([0.0], np.cumsum(values)))

        s_w, s_t, s_x = sums(w), sums(w * tc), sums(w * x)
        s_tt, s_tx = sums(w * tc * tc), sums(w * tc * x)
        lo = np.searchsorted(t, t - SPEED_WINDOW_S / 2, side="left")
        hi = np.searchsorted(t, t + SPEED_WINDOW_S / 2, side="right")
        n = s_w[hi] - s_w[lo]
        st, sx = s_t[hi] - s_t[lo], s_x[hi] - s_x[lo]
        stt, stx = s_tt[hi] - s_tt[lo], s_tx[hi] - s_tx[lo]
        with np.errstate(divide="ignore", invalid="ignore"):
            spread = stt - st * st / n
            slope = (stx - st * sx / n) / spread
            position = sx / n + slope * (tc - st / n)
        known = (n >= MIN_FIXES_PER_WINDOW) & (spread > 1e-9)
        return cls(t, np.where(known, position, np.nan), np.where(known, slope, np.nan), known)

    def speed_at(self, t_s: float) -> float:
        known = self.known
        return float(np.interp(t_s, self.t_s[known], self.speed_mps[known]))

    def position_at(self, t_s: float) -> float:
        known = self.known
        return float(np.interp(t_s, self.t_s[known], self.position_m[known]))


def _unwrapped(track_m: np.ndarray, rail_length_m: float) -> np.ndarray:
    if not len(track_m):
        return track_m
    delta = np.diff(track_m)
    delta = (delta + rail_length_m / 2) % rail_length_m - rail_length_m / 2
    return np.concatenate(([track_m[0]], track_m[0] + np.cumsum(delta)))


def _segment_starts(columns: SampleColumns, count: int) -> list[float]:
    """The time of each segment's first sample, in order, and the end of the last."""
    starts: list[float] = []
    for k in range(count):
        inside = columns.segment == k
        if not inside.any():
            break
        starts.append(float(columns.t_s[inside][0]))
    if len(starts) == count:
        after = columns.t_s[columns.t_s > starts[-1]]
        ended = ~np.isnan(columns.segment) & (columns.segment == count - 1)
        starts.append(float(columns.t_s[ended][-1]) if ended.any() else float(after[-1]))
    return starts


def _first_at_least(
    t: np.ndarray, values: np.ndarray, known: np.ndarray, from_s: float, level: float
) -> float:
    reached = known & (t >= from_s) & (values >= level)
    if not reached.any():
        raise NotMeasurable(f"the robot never reached {level:.2f} m/s")
    return float(t[reached][0])


def _lowest_median(t: np.ndarray, values: np.ndarray, from_s: float, to_s: float) -> float:
    lowest = math.inf
    start = from_s
    while start < to_s or lowest == math.inf:
        window = values[(t >= start) & (t < start + BATTERY_WINDOW_S)]
        if len(window):
            lowest = min(lowest, float(np.median(window)))
        elif start >= to_s:
            break
        start += BATTERY_WINDOW_S / 2
    if lowest == math.inf:
        raise NotMeasurable("no battery reading while accelerating")
    return lowest


def _still_from(t: np.ndarray, track: GroundTrack, from_s: float) -> float:
    """When the robot came to a stand after ``from_s``: its ground speed first under
    STILL_MPS (it only falls while the robot brakes)."""
    still = track.known & (t >= from_s) & (np.abs(track.speed_mps) < STILL_MPS)
    if not still.any():
        raise NotMeasurable("the robot did not come to a stand after its fastest step")
    return float(t[still][0])


# --- judging ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Rule:
    """A figure's limits: ``higher_is_worse``; the limit any robot must meet (a function of
    the check's speed and acceleration), and how far it may move from its baseline."""

    label: str
    unit: str
    higher_is_worse: bool
    tolerance: float  # from the baseline, in the figure's unit


def _absolute_limit(name: str, v_mps: float, a_mps2: float) -> float:
    """The limit any healthy robot meets, from the check's own speed and acceleration."""
    match name:
        case "tracking_error_mps":
            return 0.05 + 0.03 * v_mps
        case "accel_mps2":
            return 0.8 * a_mps2
        case "lag_s":
            return 0.8
        case "stop_distance_m":
            # The ramp down's v²/2a plus 0.5 s at speed (the robot's lag), and 20 cm.
            return v_mps * v_mps / (2 * a_mps2) + 0.5 * v_mps + 0.2
        case "stop_time_s":
            return v_mps / a_mps2 + 1.0
        case "battery_sag_v":
            return 0.5
        case "link_loss_share":
            return 0.05
        case "cpu_temp_c":
            # A Raspberry Pi starts to slow itself down at 80 °C.
            return 75.0
        case "rtk_share":
            return 0.9
    raise KeyError(name)


# In the order a hold's reason names them: the GPS first, as without it the motion's figures
# say little.
RULES: Final[Mapping[str, Rule]] = {
    "rtk_share": Rule("share of the lap with an RTK fix", "", False, 0.1),
    "tracking_error_mps": Rule("velocity tracking error", "m/s", True, 0.03),
    "accel_mps2": Rule("acceleration reached", "m/s²", False, 0.1),
    "lag_s": Rule("lag behind the command", "s", True, 0.2),
    "stop_distance_m": Rule("stopping distance", "m", True, 0.3),
    "stop_time_s": Rule("stopping time", "s", True, 0.5),
    "battery_sag_v": Rule("battery sag under load", "V", True, 0.3),
    "link_loss_share": Rule("radio link loss", "", True, 0.05),
    "cpu_temp_c": Rule("base station CPU temperature", "°C", True, 10.0),
}


@dataclass(frozen=True)
class Problem:
    figure: str
    text: str


def self_check_judge(
    figures: Mapping[str, float | None],
    *,
    check_velocity_mps: float,
    accel_mps2: float,
    baseline: Mapping[str, float | None] | None,
    unmeasured: str = "",
) -> list[Problem]:
    """What is out of tolerance, each said in a line an admin can act on; [] when healthy.
    ``unmeasured``: why the motion's figures are missing (a problem of its own)."""
    problems: list[Problem] = []
    for name, rule in RULES.items():
        value = figures.get(name)
        if value is None:
            continue  # not measured: the caller says why (``Figures.unmeasured``)
        limit = _absolute_limit(name, check_velocity_mps, accel_mps2)
        if (rule.higher_is_worse and value > limit) or (not rule.higher_is_worse and value < limit):
            word = "over" if rule.higher_is_worse else "under"
            problems.append(
                Problem(name, f"{rule.label} {_fmt(value, rule)} is {word} {_fmt(limit, rule)}")
            )
            continue
        base = None if baseline is None else baseline.get(name)
        if base is None:
            continue
        bound = base + rule.tolerance if rule.higher_is_worse else base - rule.tolerance
        if (rule.higher_is_worse and value > bound) or (not rule.higher_is_worse and value < bound):
            problems.append(
                Problem(
                    name,
                    f"{rule.label} {_fmt(value, rule)} is beyond its baseline "
                    f"{_fmt(base, rule)} ± {_fmt(rule.tolerance, rule)}",
                )
            )
    if unmeasured:
        problems.append(Problem("motion", f"the motion could not be measured: {unmeasured}"))
    return problems


def _fmt(value: float, rule: Rule) -> str:
    if not rule.unit:
        return f"{value:.0%}" if value >= 0.1 or value == 0 else f"{value:.1%}"
    return f"{value:.2f} {rule.unit}"
