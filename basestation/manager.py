"""The run manager: what the robot is told to do at each control tick, and what is kept.

:meth:`RunManager.tick` is the whole behaviour of the agent in time. It is called by the
control loop thread, and directly by tests with a fake clock. HTTP threads never drive the
robot: they change runs in the store and call :meth:`RunManager.notify_runs_changed`; the
next tick picks the change up.
"""

from __future__ import annotations

import logging
import sqlite3
import statistics
import threading
from collections import deque
from dataclasses import dataclass

from basestation.config import AgentConfig
from basestation.robot import (
    Command,
    Direction,
    Robot,
    RobotLinkError,
    Telemetry,
    signed_velocity_mps,
)
from basestation.store import (
    COMPLETED,
    FAILED,
    INTERRUPTED,
    RUNNING,
    STAGED,
    RunRecord,
    RunStore,
    Sample,
)

logger = logging.getLogger(__name__)

# Measured speed under which the robot counts as stopped: above the encoder noise (0.01 m/s),
# below any speed an experiment would ask for.
STOPPED_BELOW_MPS = 0.02
# The battery reading is median-filtered (thesis fig. 3.20: a median rejects the spikes that
# a mean smears); 9 samples is under half a second at 20 Hz.
BATTERY_WINDOW = 9
# The schedule is re-read at least this often even without a change notice, so a missed
# notice can delay a start by at most this much.
REFRESH_INTERVAL_S = 1.0


@dataclass(frozen=True)
class AgentSnapshot:
    """What the last tick saw; replaced whole each tick so HTTP threads read it lock-free."""

    ticks: int = 0
    link_errors: int = 0
    telemetry: Telemetry | None = None
    telemetry_at_s: float | None = None  # agent clock of the last telemetry frame
    battery_v: float | None = None  # median-filtered
    current_run: str | None = None


class RunManager:
    def __init__(self, *, store: RunStore, robot: Robot, config: AgentConfig) -> None:
        self.store = store
        self.robot = robot
        self.config = config
        self._tick_lock = threading.Lock()
        self._runs_changed = threading.Event()
        self._schedule: list[RunRecord] = []
        self._last_refresh_s: float | None = None
        self._active: RunRecord | None = None
        self._next_seq = 1
        self._last_tick_s: float | None = None
        # The velocity the robot is told (cw positive), slewed at the run's acceleration
        # limit when that is gentler than the robot's own ramp.
        self._setpoint_signed_mps = 0.0
        self._direction: Direction = "cw"
        self._battery_window: deque[float] = deque(maxlen=BATTERY_WINDOW)
        self.snapshot = AgentSnapshot()

    def notify_runs_changed(self) -> None:
        """Called by HTTP threads after they commit a change to the runs."""
        self._runs_changed.set()

    def tick(self, now_s: float) -> None:
        """One control period at agent time ``now_s`` (epoch seconds)."""
        with self._tick_lock:
            self._tick(now_s)

    def shutdown(self, now_s: float) -> None:
        """Command the robot to zero and close the current run (the agent is stopping)."""
        with self._tick_lock:
            try:
                self.robot.exchange(Command(velocity_mps=0.0, direction=self._direction), now_s)
            except RobotLinkError:
                # The firmware's dead-man stops the robot within 500 ms of our silence anyway.
                logger.warning("no answer to the final stop command")
            if self._active is not None:
                self.store.transition(
                    self._active.id,
                    from_states=[RUNNING],
                    to_state=INTERRUPTED,
                    reason="agent stopped during run",
                    now_s=now_s,
                )
                self._active = None

    # -- the tick ------------------------------------------------------------------------------

    def _tick(self, now_s: float) -> None:
        if (
            self._runs_changed.is_set()
            or self._last_refresh_s is None
            or now_s - self._last_refresh_s >= REFRESH_INTERVAL_S
        ):
            self._runs_changed.clear()
            self._refresh(now_s)

        run = self._active
        if run is not None and now_s >= run.spec.end_at_s:
            # The booked window is over: no more motion for this run, whatever its state.
            self._finish(run, now_s, "booked window ended before the robot had stopped")
            run = None
        if run is None:
            run = self._start_due_run(now_s)

        segment: int | None = None
        commanded_mps = 0.0
        accel_mps2 = self.config.max_accel_mps2
        if run is not None:
            segment, commanded_mps, self._direction = run.spec.program_at(now_s)
            accel_mps2 = min(accel_mps2, run.spec.limits.max_accel_mps2)

        command = self._slew(now_s, signed_velocity_mps(commanded_mps, self._direction), accel_mps2)
        self._last_tick_s = now_s
        telemetry: Telemetry | None
        try:
            telemetry = self.robot.exchange(command, now_s)
        except RobotLinkError as exc:
            # No frame, no sample: nothing is invented. The link age in /status shows it.
            logger.debug("no telemetry at %.3f: %s", now_s, exc)
            telemetry = None

        if telemetry is not None:
            self._battery_window.append(telemetry.battery_v)
            if run is not None:
                self._record(run, now_s, segment, commanded_mps, telemetry)
                program_over = now_s >= run.spec.start_at_s + run.spec.program_duration_s
                if (
                    self._active is not None
                    and program_over
                    and telemetry.velocity_mps < STOPPED_BELOW_MPS
                ):
                    self._finish(run, now_s, "program finished")

        previous = self.snapshot
        self.snapshot = AgentSnapshot(
            ticks=previous.ticks + 1,
            link_errors=previous.link_errors + (1 if telemetry is None else 0),
            telemetry=telemetry if telemetry is not None else previous.telemetry,
            telemetry_at_s=now_s if telemetry is not None else previous.telemetry_at_s,
            battery_v=(statistics.median(self._battery_window) if self._battery_window else None),
            current_run=self._active.id if self._active is not None else None,
        )

    def _slew(self, now_s: float, target_signed_mps: float, accel_mps2: float) -> Command:
        period_s = self.config.control_period_s
        dt_s = period_s if self._last_tick_s is None else now_s - self._last_tick_s
        # A late tick may catch up by at most two periods; a stepped clock must not jump.
        dt_s = min(max(dt_s, 0.0), 2 * period_s)
        max_step_mps = accel_mps2 * dt_s
        error_mps = target_signed_mps - self._setpoint_signed_mps
        self._setpoint_signed_mps += min(max(error_mps, -max_step_mps), max_step_mps)
        setpoint_mps = self._setpoint_signed_mps
        if setpoint_mps > 0:
            direction: Direction = "cw"
        elif setpoint_mps < 0:
            direction = "ccw"
        else:
            direction = self._direction
        return Command(velocity_mps=abs(setpoint_mps), direction=direction)

    def _record(
        self,
        run: RunRecord,
        now_s: float,
        segment: int | None,
        commanded_mps: float,
        telemetry: Telemetry,
    ) -> None:
        sample = Sample(
            seq=self._next_seq,
            t=now_s,
            segment=segment,
            commanded_velocity_mps=commanded_mps,
            velocity_mps=telemetry.velocity_mps,
            direction=telemetry.direction,
            battery_v=telemetry.battery_v,
            track_m=telemetry.track_m,
        )
        try:
            stored = self.store.append_samples(run.id, [sample])
        except sqlite3.Error:
            # The seq is spent anyway: a gap tells the portal exactly what is missing,
            # where silently reusing it would hide the loss.
            logger.exception("run %s: sample %d not stored", run.id, sample.seq)
            self._next_seq += 1
            return
        if stored:
            self._next_seq += 1
        else:
            # Someone ended the run under us (an abort from the API): let go of it, and the
            # next ticks command zero.
            self._active = None

    # -- the schedule ----------------------------------------------------------------------------

    def _refresh(self, now_s: float) -> None:
        self._last_refresh_s = now_s
        self._schedule = self.store.staged_runs()
        if self._active is not None:
            current = self.store.get_run(self._active.id)
            if current is None or current.state != RUNNING:
                self._active = None

    def _start_due_run(self, now_s: float) -> RunRecord | None:
        for record in list(self._schedule):
            if record.spec.start_at_s > now_s:
                break  # the schedule is ordered by start: nothing later is due either
            self._schedule.remove(record)
            if record.spec.end_at_s <= now_s:
                self.store.transition(
                    record.id,
                    from_states=[STAGED],
                    to_state=FAILED,
                    reason="the booked window passed while the agent was not running",
                    now_s=now_s,
                )
                continue
            late_s = now_s - record.spec.start_at_s
            reason = "started" if late_s < 1.0 else f"started {late_s:.1f} s late"
            if self.store.transition(
                record.id, from_states=[STAGED], to_state=RUNNING, reason=reason, now_s=now_s
            ):
                self._active = record
                last_seq = self.store.sample_stats(record.id).last_seq
                self._next_seq = 1 if last_seq is None else last_seq + 1
                return record
        return None

    def _finish(self, run: RunRecord, now_s: float, reason: str) -> None:
        self.store.transition(
            run.id, from_states=[RUNNING], to_state=COMPLETED, reason=reason, now_s=now_s
        )
        self._active = None
