"""The run manager: what the robot is told to do at each control tick, and what is kept.

:meth:`RunManager.tick` is the whole behaviour of the agent in time. It is called by the
control loop thread, and directly by tests with a fake clock. HTTP threads never drive the
robot: they change runs in the store and call :meth:`RunManager.notify_runs_changed`, or
hand over a manual command or the e-stop latch (:meth:`RunManager.drive_manually`,
:meth:`RunManager.latch_estop`); the next tick picks the change up.

What the robot is told, in order of precedence: the e-stop latch (stop flag, velocity 0);
the running run's program, only inside its booked window; an admin's manual command until
its time-to-live runs out; otherwise velocity 0.
"""

from __future__ import annotations

import logging
import math
import sqlite3
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from basestation.config import AgentConfig
from basestation.errors import RunConflict
from basestation.program import format_epoch
from basestation.robot import (
    Command,
    Direction,
    Robot,
    RobotLinkError,
    Telemetry,
    signed_velocity_mps,
)
from basestation.store import (
    ABORTED,
    COMPLETED,
    FAILED,
    INTERRUPTED,
    RUNNING,
    STAGED,
    RunRecord,
    RunStore,
    Sample,
)
from basestation.telemetry.battery import BatteryFilter
from basestation.telemetry.laps import LapCounter
from basestation.writer import StoreWriter, WriterFull

logger = logging.getLogger(__name__)

# Measured speed under which the robot counts as stopped: above the encoder noise (0.01 m/s),
# below any speed an experiment would ask for.
STOPPED_BELOW_MPS = 0.02
# The battery reading is median-filtered (thesis fig. 3.20: a median rejects the spikes that
# a mean smears); 9 samples is under half a second at 20 Hz.
BATTERY_WINDOW = 9
# A running run is aborted only when the filtered battery stays low this long: the voltage
# sags for a moment while the robot accelerates, and a false abort costs an experiment.
LOW_BATTERY_HOLD_S = 2.0
# The schedule is re-read at least this often even without a change notice, so a missed
# notice can delay a start by at most this much.
REFRESH_INTERVAL_S = 1.0
# Link loss is counted over the last this many exchanges (5 s at 20 Hz).
LOSS_WINDOW = 100


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
    loss_pct: float | None = None  # exchanges without telemetry, over the last LOSS_WINDOW
    current_run: str | None = None
    command: Command | None = None  # what the last tick sent


class RunManager:
    def __init__(self, *, store: RunStore, robot: Robot, config: AgentConfig) -> None:
        self.store = store
        self.robot = robot
        self.config = config
        # The tick's writes (samples, run transitions) go through the writer: inline until
        # the runtime starts its thread (see basestation.writer).
        self.writer = StoreWriter(
            store,
            capacity=max(1, math.ceil(60 * config.control_hz)),
            on_refused=lambda run_id: self.notify_runs_changed(),
        )
        self._tick_lock = threading.Lock()
        self._runs_changed = threading.Event()
        self._schedule: list[RunRecord] = []
        self._last_refresh_s: float | None = None
        self._active: RunRecord | None = None
        self._next_seq = 1
        self._last_tick_s: float | None = None
        # The control loop's wake(), once it runs; without a loop (tests that tick by hand)
        # the stop frame goes with the next tick.
        self.on_wake: Callable[[], None] | None = None
        # The velocity the robot is told (cw positive), slewed at the run's acceleration
        # limit when that is gentler than the robot's own ramp.
        self._setpoint_signed_mps = 0.0
        self._direction: Direction = "cw"
        self._battery = BatteryFilter(BATTERY_WINDOW)
        # Whole laps of the active run, from its unwrapped track position.
        self._laps: tuple[str, LapCounter] | None = None
        self._low_battery_since_s: float | None = None
        self._answered: deque[bool] = deque(maxlen=LOSS_WINDOW)
        # Set by HTTP threads, read by the tick: whole objects swapped, never mutated.
        # _api_lock serialises the HTTP-side operations; _manual_lock only guards the
        # compare-and-swap of _manual between them and the tick (held for no I/O).
        self._api_lock = threading.Lock()
        self._manual_lock = threading.Lock()
        self._manual: ManualDrive | None = None
        latched = store.get_estop()
        self._estop: EstopLatch | None = (
            None if latched is None else EstopLatch(since_s=latched[0], reason=latched[1])
        )
        # Every accepted stop request puts at least one stop frame on air, even when it is
        # released again before the next tick.
        self._estop_frame_owed = self._estop is not None
        self.snapshot = AgentSnapshot()

    @property
    def estop(self) -> EstopLatch | None:
        return self._estop

    def manual(self, now_s: float) -> ManualDrive | None:
        """The manual command in force at ``now_s``, if any."""
        manual = self._manual
        return manual if manual is not None and now_s < manual.expires_at_s else None

    def wake(self) -> None:
        """Ask the control loop for :meth:`urgent` now; the runtime connects it."""
        if self.on_wake is not None:
            self.on_wake()

    def notify_runs_changed(self) -> None:
        """Called by HTTP threads after they commit a change to the runs."""
        self._runs_changed.set()

    def tick(self, now_s: float) -> None:
        """One control period at agent time ``now_s`` (epoch seconds)."""
        with self._tick_lock:
            self._tick(now_s)

    def urgent(self, now_s: float) -> None:
        """Between two ticks: send a stop frame owed, or start a run whose time has come (a
        tick out of turn: the ramp works from the time since the last tick, so an extra one
        changes nothing else)."""
        with self._tick_lock:
            start_s = self.next_start_s()
            if self._estop_frame_owed or (start_s is not None and start_s <= now_s):
                self._tick(now_s)

    def next_start_s(self) -> float | None:
        """When the next staged run starts (epoch seconds): the control loop wakes then."""
        # Read from the loop's thread between ticks; the list only changes inside a tick.
        if self._active is not None:
            return None
        try:
            return self._schedule[0].spec.start_at_s
        except IndexError:
            return None

    def shutdown(self, now_s: float) -> None:
        """Command the robot to zero and close the current run (the agent is stopping)."""
        with self._tick_lock:
            try:
                self.robot.exchange(
                    Command(
                        velocity_mps=0.0, direction=self._direction, estop=self._estop is not None
                    ),
                    now_s,
                )
            except RobotLinkError:
                # The firmware's dead-man stops the robot within 500 ms of our silence anyway.
                logger.warning("no answer to the final stop command")
            manual = self._take_manual(None)
            if manual is not None:
                self.store.manual_session_end(manual.session_id, ended_at_s=now_s)
            if self._active is not None:
                self._transition(
                    self._active.id, RUNNING, INTERRUPTED, "agent stopped during run", now_s
                )
                self._active = None
            self.writer.flush()

    # -- operations called by HTTP threads ---------------------------------------------------

    def latch_estop(self, *, now_s: float, reason: str) -> tuple[EstopLatch, str | None]:
        """Latch the e-stop: the next tick sends the stop flag (at most one period from now),
        manual control ends, a running run is aborted. Returns (latch, aborted run id).
        Latching again keeps the first latch's time and reason."""
        with self._api_lock:
            latch = self._estop
            if latch is None:
                latch = EstopLatch(since_s=now_s, reason=reason)
                # Memory first, so the very next tick stops the robot; the store keeps the
                # latch across a restart of the agent.
                self._estop = latch
                self._estop_frame_owed = True
                self.store.set_estop(since_s=now_s, reason=reason)
                logger.warning("e-stop latched: %s", reason)
                self.wake()
            manual = self._take_manual(None)
            if manual is not None:
                self.store.manual_session_end(manual.session_id, ended_at_s=now_s)
            aborted = self._abort_running(now_s, f"emergency stop: {latch.reason}")
        return latch, aborted

    def release_estop(self, *, now_s: float) -> bool:
        """Release the latch (also the robot's own, e.g. one kept across its restart).
        Returns False when it was not latched. The robot moves again only on a later
        command: a run due meanwhile starts, late, at the next tick."""
        with self._api_lock:
            release_robot = getattr(self.robot, "release_estop", None)
            if callable(release_robot):
                release_robot()
            if self._estop is None:
                return False
            # Store first: a crash in between leaves the agent latched, the safe side.
            self.store.clear_estop()
            self._estop = None
            logger.warning("e-stop released")
            self.notify_runs_changed()
            return True

    def drive_manually(
        self,
        *,
        now_s: float,
        user: str,
        velocity_mps: float,
        direction: Direction,
        ttl_s: float,
        force: bool,
    ) -> tuple[ManualDrive | None, str | None]:
        """Hold ``velocity_mps`` in ``direction`` for ``ttl_s`` (each command renews the
        dead-man); velocity 0 ends manual control. Returns (manual command in force, id of
        the run aborted to make way).

        Raises :class:`RunConflict` ``estop_latched``, or ``robot_busy`` while a run is
        running unless ``force`` (which aborts the run).
        """
        with self._api_lock:
            if self._estop is not None:
                raise RunConflict(
                    "estop_latched",
                    "the emergency stop is latched: release it (POST /stop/release) first",
                )
            aborted = None
            running = self.store.running_run_id()
            if running is not None:
                if not force:
                    raise RunConflict(
                        "robot_busy",
                        f'run {running} holds the robot; send "force": true to abort it '
                        "and take over",
                    )
                aborted = self._abort_running(now_s, f"aborted: {user} took manual control")
            current = self.manual(now_s)
            if velocity_mps == 0:
                if current is not None and self._take_manual(current) is current:
                    self.store.manual_session_end(current.session_id, ended_at_s=now_s)
                return None, aborted
            expires_at_s = now_s + ttl_s
            if current is not None and current.user == user:
                self.store.manual_session_extend(current.session_id, until_s=expires_at_s)
                drive = replace(
                    current,
                    velocity_mps=velocity_mps,
                    direction=direction,
                    expires_at_s=expires_at_s,
                )
            else:
                if current is not None:
                    self.store.manual_session_end(current.session_id, ended_at_s=now_s)
                session_id = self.store.manual_session_open(
                    user=user, started_at_s=now_s, until_s=expires_at_s
                )
                drive = ManualDrive(
                    user=user,
                    velocity_mps=velocity_mps,
                    direction=direction,
                    session_started_at_s=now_s,
                    expires_at_s=expires_at_s,
                    session_id=session_id,
                )
            with self._manual_lock:
                self._manual = drive
            return drive, aborted

    def _abort_running(self, now_s: float, reason: str) -> str | None:
        run_id = self.store.running_run_id()
        if run_id is not None and self.store.transition(
            run_id, from_states=[RUNNING], to_state=ABORTED, reason=reason, now_s=now_s
        ):
            self.notify_runs_changed()
            return run_id
        return None

    def _take_manual(self, expected: ManualDrive | None) -> ManualDrive | None:
        """Clear the manual command if it is still ``expected`` (None: whatever it is);
        returns what was cleared."""
        with self._manual_lock:
            current = self._manual
            if current is None or (expected is not None and current is not expected):
                return None
            self._manual = None
            return current

    # -- the tick ------------------------------------------------------------------------------

    def _tick(self, now_s: float) -> None:
        if (
            self._runs_changed.is_set()
            or self._last_refresh_s is None
            or now_s - self._last_refresh_s >= REFRESH_INTERVAL_S
        ):
            self._runs_changed.clear()
            self._refresh(now_s)

        estop = self._estop
        run = self._active
        if run is not None and estop is not None:
            # The HTTP thread that latched it has aborted the run already; this covers a
            # latch that found no run yet in the store.
            self._abort(run, now_s, f"emergency stop: {estop.reason}")
            run = None
        if run is not None and now_s >= run.spec.end_at_s:
            # The booked window is over: no more motion for this run, whatever its state.
            self._finish(run, now_s, "booked window ended before the robot had stopped")
            run = None
        if run is not None and self._battery_low_for(now_s) >= LOW_BATTERY_HOLD_S:
            battery_v = self.snapshot.battery_v
            self._abort(
                run,
                now_s,
                f"battery low: {battery_v:.1f} V, below {self.config.low_battery_v:g} V "
                "(AGENT_LOW_BATTERY_V)",
            )
            run = None
        if run is None:
            if estop is None:
                run = self._start_due_run(now_s)
            else:
                self._fail_passed_runs(
                    now_s, "the booked window passed while the emergency stop was latched"
                )

        manual = self.manual(now_s)
        if manual is not None and (run is not None or estop is not None):
            # A booked run takes the robot from manual control (an e-stop ends it too).
            if self._take_manual(manual) is manual:
                session_id = manual.session_id
                self.writer.submit(
                    lambda: self.store.manual_session_end(session_id, ended_at_s=now_s)
                )
                logger.info(
                    "manual control by %s ended: %s",
                    manual.user,
                    "e-stop latched" if run is None else f"run {run.id} starts",
                )
            manual = None

        segment: int | None = None
        commanded_mps = 0.0
        accel_mps2 = self.config.max_accel_mps2
        if run is not None:
            # Motion for a run only inside its booked window (a clock stepped back must not
            # replay the program early).
            if run.spec.start_at_s <= now_s < run.spec.end_at_s:
                segment, commanded_mps, self._direction = run.spec.program_at(now_s)
            accel_mps2 = min(accel_mps2, run.spec.limits.max_accel_mps2)
        elif manual is not None:
            commanded_mps, self._direction = manual.velocity_mps, manual.direction

        if estop is not None or self._estop_frame_owed:
            # The robot brakes by itself on the flag; our ramp restarts from zero after release.
            self._estop_frame_owed = False
            self._setpoint_signed_mps = 0.0
            command = Command(velocity_mps=0.0, direction=self._direction, estop=True)
        else:
            command = self._slew(
                now_s, signed_velocity_mps(commanded_mps, self._direction), accel_mps2
            )
        self._last_tick_s = now_s
        telemetry: Telemetry | None
        try:
            telemetry = self.robot.exchange(command, now_s)
        except RobotLinkError as exc:
            # No frame, no sample: nothing is invented. The link age in /status shows it.
            logger.debug("no telemetry at %.3f: %s", now_s, exc)
            telemetry = None
        self._answered.append(telemetry is not None)

        if telemetry is not None:
            # 0 V is the robot's "not measured yet" (before its first ADC reading after a
            # reset, docs/protocol.md): no real pack reads 0 V, and a median must not take it.
            if math.isfinite(telemetry.battery_v) and telemetry.battery_v > 0:
                self._battery.add(telemetry.battery_v)
            if run is not None:
                self._record(run, now_s, segment, commanded_mps, telemetry)
                program_over = now_s >= run.spec.start_at_s + run.spec.program_duration_s
                if (
                    self._active is not None
                    and program_over
                    and telemetry.velocity_mps < STOPPED_BELOW_MPS
                ):
                    self._finish(run, now_s, "program finished")

        battery_v = self._battery.battery_v
        threshold_v = self.config.low_battery_v
        low = threshold_v > 0 and battery_v is not None and battery_v < threshold_v
        if not low:
            self._low_battery_since_s = None
        elif self._low_battery_since_s is None:
            self._low_battery_since_s = now_s
        previous = self.snapshot
        answered = self._answered
        self.snapshot = AgentSnapshot(
            ticks=previous.ticks + 1,
            link_errors=previous.link_errors + (1 if telemetry is None else 0),
            telemetry=telemetry if telemetry is not None else previous.telemetry,
            telemetry_at_s=now_s if telemetry is not None else previous.telemetry_at_s,
            battery_v=battery_v,
            battery_raw_v=(
                telemetry.battery_v if telemetry is not None else previous.battery_raw_v
            ),
            battery_low=low,
            loss_pct=100.0 * answered.count(False) / len(answered),
            current_run=self._active.id if self._active is not None else None,
            command=command,
        )

    def _battery_low_for(self, now_s: float) -> float:
        since_s = self._low_battery_since_s
        return 0.0 if since_s is None else now_s - since_s

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
        # A radio robot reports its position (RadioTelemetry); the kinematic model does not.
        position_known = getattr(telemetry, "position_known", False)
        sample = Sample(
            seq=self._next_seq,
            t=now_s,
            segment=segment,
            commanded_velocity_mps=commanded_mps,
            velocity_mps=telemetry.velocity_mps,
            direction=telemetry.direction,
            battery_v=(
                telemetry.battery_v
                if telemetry.battery_v > 0
                else (self._battery.battery_v or telemetry.battery_v)
            ),
            track_m=telemetry.track_m,
            fix_quality=getattr(telemetry, "fix_quality", None),
            lat_deg=getattr(telemetry, "lat_deg", None) if position_known else None,
            lon_deg=getattr(telemetry, "lon_deg", None) if position_known else None,
            grid_id=getattr(telemetry, "grid_id", None) if position_known else None,
            lap=self._lap(run.id, telemetry.track_m, now_s, telemetry.velocity_mps),
        )
        try:
            stored = self.writer.append(run.id, sample)
        except (sqlite3.Error, WriterFull):
            # The seq is spent anyway: a gap tells the portal exactly what is missing,
            # where silently reusing it would hide the loss.
            logger.exception("run %s: sample %d not stored", run.id, sample.seq)
            self._next_seq += 1
            return
        if stored is False:
            # Someone ended the run under us (an abort from the API): let go of it, and the
            # next ticks command zero. (Queued writes learn it later: the writer's refusal
            # triggers a refresh, which lets go of the run the same way.)
            self._active = None
        else:
            self._next_seq += 1

    def _lap(self, run_id: str, track_m: float, now_s: float, velocity_mps: float) -> int:
        if self._laps is None or self._laps[0] != run_id:
            self._laps = (run_id, LapCounter(self.rail_length_m))
        self._laps[1].update(track_m, now_s, velocity_mps)
        return self._laps[1].laps

    @property
    def rail_length_m(self) -> float:
        """The length at which ``track_m`` wraps: the rail file's when there is one."""
        rail = getattr(self.robot, "rail", None)  # the radio link knows the configured rail
        length = getattr(rail, "length_m", None)
        return float(length) if length else self.config.rail_length_m

    # -- the schedule ----------------------------------------------------------------------------

    def _refresh(self, now_s: float) -> None:
        self._last_refresh_s = now_s
        if self._active is not None:
            current = self.store.get_run(self._active.id)
            # Still "staged" in the store: our start is queued with the writer, not lost.
            if current is None or current.state not in (RUNNING, STAGED):
                self._active = None
        active_id = None if self._active is None else self._active.id
        self._schedule = [run for run in self.store.staged_runs() if run.id != active_id]

    def _start_due_run(self, now_s: float) -> RunRecord | None:
        for record in list(self._schedule):
            if record.spec.start_at_s > now_s:
                break  # the schedule is ordered by start: nothing later is due either
            self._schedule.remove(record)
            if record.spec.end_at_s <= now_s:
                reason = "the booked window passed while the agent was not running"
                self._transition(record.id, STAGED, FAILED, reason, now_s)
                continue
            if self.snapshot.battery_low:
                reason = (
                    f"not started: battery at {self.snapshot.battery_v:.1f} V, below "
                    f"{self.config.low_battery_v:g} V (AGENT_LOW_BATTERY_V)"
                )
                self._transition(record.id, STAGED, FAILED, reason, now_s)
                continue
            late_s = now_s - record.spec.start_at_s
            reason = "started" if late_s < 1.0 else f"started {late_s:.1f} s late"
            # Queued with the writer, the start is optimistic: should an HTTP thread have
            # cancelled the run a moment ago, the writer refuses its samples and the next
            # refresh lets go of it. A run starts once, so its samples begin at seq 1.
            if self._transition(record.id, STAGED, RUNNING, reason, now_s) is not False:
                self._active = record
                self._next_seq = 1
                return record
        return None

    def _transition(
        self, run_id: str, from_state: str, to_state: str, reason: str, now_s: float
    ) -> bool | None:
        """A run transition in order with the samples (None: queued, applied later)."""

        def apply() -> bool:
            return self.store.transition(
                run_id, from_states=[from_state], to_state=to_state, reason=reason, now_s=now_s
            )

        result = self.writer.submit(apply)
        return None if result is None else bool(result)

    def _fail_passed_runs(self, now_s: float, reason: str) -> None:
        """Runs due but held back (e-stop) stay staged until their window has passed."""
        for record in list(self._schedule):
            if record.spec.start_at_s > now_s:
                break
            if record.spec.end_at_s <= now_s:
                self._schedule.remove(record)
                self._transition(record.id, STAGED, FAILED, reason, now_s)

    def _finish(self, run: RunRecord, now_s: float, reason: str) -> None:
        self._transition(run.id, RUNNING, COMPLETED, reason, now_s)
        self._active = None

    def _abort(self, run: RunRecord, now_s: float, reason: str) -> None:
        """End the run now; the following ticks ramp the robot to zero (no run, no manual)."""
        self._transition(run.id, RUNNING, ABORTED, reason, now_s)
        self._active = None
