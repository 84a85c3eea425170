"""The rule book of a control tick: what the robot is told, as a pure function.

:func:`decide` is a pure function of what the tick knows (e-stop latch, running run, staged
runs, manual command, battery, clock): it says which run ends, fails or starts and what to
command. It has no side effects; :class:`basestation.manager.RunManager` calls it every tick,
applies the state changes, makes the one exchange with the robot, and records what came
back. The values the tick and the API hand around live here too: the manual command, the
e-stop latch, the decision, and the snapshot of what the last tick saw.

What the robot is told, in order of precedence:

1. the e-stop latch: the stop flag and velocity 0. It aborts the running run and ends manual
   control; no run starts while it holds, and a run whose window passes meanwhile fails;
2. the running run's program, only inside its booked window. The end of the window finishes
   the run; a filtered battery held below ``AGENT_LOW_BATTERY_V`` for ``LOW_BATTERY_HOLD_S``
   aborts it (and a run due on a low battery fails instead of starting). A booked run takes
   the robot from manual control;
3. an admin's manual command, until its time-to-live runs out;
4. otherwise velocity 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from basestation.program import format_epoch
from basestation.robot import Command, Direction, Telemetry
from basestation.store import ABORTED, COMPLETED, RunRecord

# A running run is aborted only when the filtered battery stays low this long: the voltage
# sags for a moment while the robot accelerates, and a false abort costs an experiment.
LOW_BATTERY_HOLD_S = 2.0


@dataclass(frozen=True)
class ManualDrive:
    """An admin's manual command, held until ``expires_at_s`` (the dead-man)."""

    user: str
    velocity_mps: float
    direction: Direction
    session_started_at_s: float
    expires_at_s: float
    session_id: int

    def to_json_dict(self, now_s: float) -> dict[str, Any]:
        return {
            "user": self.user,
            "velocity_mps": self.velocity_mps,
            "direction": self.direction,
            "since": format_epoch(self.session_started_at_s),
            "expires_at": format_epoch(self.expires_at_s),
            "ttl_s": max(0.0, self.expires_at_s - now_s),
        }


@dataclass(frozen=True)
class EstopLatch:
    since_s: float
    reason: str

    def to_json_dict(self) -> dict[str, Any]:
        return {"latched": True, "since": format_epoch(self.since_s), "reason": self.reason}


@dataclass(frozen=True)
class AgentSnapshot:
    """What the last tick saw; replaced whole each tick so HTTP threads read it lock-free."""

    ticks: int = 0
    link_errors: int = 0
    telemetry: Telemetry | None = None
    telemetry_at_s: float | None = None  # agent clock of the last telemetry frame
    battery_v: float | None = None  # median-filtered
    battery_raw_v: float | None = None  # the last frame's reading
    battery_low: bool = False  # filtered voltage under AGENT_LOW_BATTERY_V
    loss_pct: float | None = None  # exchanges without telemetry, over the last manager.LOSS_WINDOW
    current_run: str | None = None
    command: Command | None = None  # what the last tick sent


# A staged run that will never start, and why.
RunFailure = tuple[RunRecord, str]


@dataclass(frozen=True, slots=True)
class RunEnd:
    """The running run ends: ``to_state`` is COMPLETED or ABORTED."""

    run: RunRecord
    to_state: str
    reason: str


@dataclass(frozen=True, slots=True)
class RunStart:
    run: RunRecord
    reason: str


@dataclass(frozen=True, slots=True)
class TickDecision:
    """What one tick does: state changes first, in this order, then the command.

    ``run`` and ``manual`` are what holds the robot once the changes are made;
    ``commanded_mps``, ``direction`` and ``segment`` are what the run's program or the manual
    command asks for (recorded with the sample), ``accel_mps2`` the ramp towards it. With
    ``stop`` the frame carries the e-stop flag and velocity 0 whatever was asked.
    """

    end: RunEnd | None
    fail: tuple[RunFailure, ...]
    start: RunStart | None
    end_manual: ManualDrive | None  # taken from the admin: a run or the e-stop holds the robot
    run: RunRecord | None
    manual: ManualDrive | None
    stop: bool
    segment: int | None
    commanded_mps: float
    direction: Direction
    accel_mps2: float


def decide(
    *,
    now_s: float,
    estop: EstopLatch | None,
    stop_frame_owed: bool,
    run: RunRecord | None,
    schedule: Sequence[RunRecord],
    manual: ManualDrive | None,
    battery_v: float | None,
    battery_low: bool,
    battery_low_for_s: float,
    low_battery_v: float,
    direction: Direction,
    max_accel_mps2: float,
) -> TickDecision:
    """The tick's decision at agent time ``now_s``, from what the tick knows; no side effects.

    ``run`` is the running run, ``schedule`` the staged runs by start time, ``manual`` the
    latest manual command (expired or not), ``battery_*`` the filtered battery as the last
    tick left it, ``direction`` the last one commanded (kept when nothing sets another).
    The rules are the module docstring's, in its order of precedence.
    """
    # 1. The e-stop latch aborts the running run (the HTTP thread that latched it has done so
    #    already; this covers a latch that found no run yet in the store). Then the run's own
    #    ends: its booked window is over (whatever it is doing), or the battery stayed low.
    end: RunEnd | None = None
    if run is not None:
        if estop is not None:
            end = RunEnd(run, ABORTED, f"emergency stop: {estop.reason}")
        elif now_s >= run.spec.end_at_s:
            end = RunEnd(run, COMPLETED, "booked window ended before the robot had stopped")
        elif battery_low_for_s >= LOW_BATTERY_HOLD_S:
            end = RunEnd(
                run,
                ABORTED,
                f"battery low: {battery_v:.1f} V, below {low_battery_v:g} V (AGENT_LOW_BATTERY_V)",
            )
        if end is not None:
            run = None

    # 2. With the robot free, a due run starts, unless the e-stop is latched: then due runs
    #    wait (staged) until their window has passed, and fail.
    fail: tuple[RunFailure, ...] = ()
    start: RunStart | None = None
    if run is None:
        if estop is None:
            fail, start = _due_run(
                now_s,
                schedule,
                battery_low=battery_low,
                battery_v=battery_v,
                low_battery_v=low_battery_v,
            )
            if start is not None:
                run = start.run
        else:
            fail = _passed_runs(
                now_s, schedule, "the booked window passed while the emergency stop was latched"
            )

    # 3. A manual command holds until its time-to-live runs out; a run holding the robot or
    #    the e-stop ends it.
    if manual is not None and now_s >= manual.expires_at_s:
        manual = None
    end_manual: ManualDrive | None = None
    if manual is not None and (run is not None or estop is not None):
        end_manual, manual = manual, None

    # 4. What the robot is told: the run's program, only inside its booked window (a clock
    #    stepped back must not replay it early), at the gentler of the two acceleration
    #    limits; else the manual command; else velocity 0. The e-stop flag overrides both,
    #    and goes out at least once for every accepted stop request, even one released since.
    segment: int | None = None
    commanded_mps = 0.0
    accel_mps2 = max_accel_mps2
    if run is not None:
        if run.spec.start_at_s <= now_s < run.spec.end_at_s:
            segment, commanded_mps, direction = run.spec.program_at(now_s)
        accel_mps2 = min(accel_mps2, run.spec.limits.max_accel_mps2)
    elif manual is not None:
        commanded_mps, direction = manual.velocity_mps, manual.direction
    return TickDecision(
        end=end,
        fail=fail,
        start=start,
        end_manual=end_manual,
        run=run,
        manual=manual,
        stop=estop is not None or stop_frame_owed,
        segment=segment,
        commanded_mps=commanded_mps,
        direction=direction,
        accel_mps2=accel_mps2,
    )


def _due_run(
    now_s: float,
    schedule: Sequence[RunRecord],
    *,
    battery_low: bool,
    battery_v: float | None,
    low_battery_v: float,
) -> tuple[tuple[RunFailure, ...], RunStart | None]:
    """The first due run that can start, and the due runs before it that never will."""
    fail: tuple[RunFailure, ...] = ()
    for record in schedule:
        if record.spec.start_at_s > now_s:
            break  # the schedule is ordered by start: nothing later is due either
        if record.spec.end_at_s <= now_s:
            fail += ((record, "the booked window passed while the agent was not running"),)
        elif battery_low:
            reason = (
                f"not started: battery at {battery_v:.1f} V, below {low_battery_v:g} V "
                "(AGENT_LOW_BATTERY_V)"
            )
            fail += ((record, reason),)
        else:
            late_s = now_s - record.spec.start_at_s
            reason = "started" if late_s < 1.0 else f"started {late_s:.1f} s late"
            return fail, RunStart(record, reason)
    return fail, None


def _passed_runs(
    now_s: float, schedule: Sequence[RunRecord], reason: str
) -> tuple[RunFailure, ...]:
    """Due runs whose window has passed (the others stay staged)."""
    fail: tuple[RunFailure, ...] = ()
    for record in schedule:
        if record.spec.start_at_s > now_s:
            break
        if record.spec.end_at_s <= now_s:
            fail += ((record, reason),)
    return fail
