"""The run manager: makes each control tick's decision happen, and keeps what came back.

:meth:`RunManager.tick` is the whole behaviour of the agent in time. It is called by the
control loop thread, and directly by tests with a fake clock. HTTP threads never drive the
robot: they change runs in the store and call :meth:`RunManager.notify_runs_changed`, or
hand over a manual command or the e-stop latch (:meth:`RunManager.drive_manually`,
:meth:`RunManager.latch_estop`); the next tick picks the change up.

A tick has three steps. :func:`basestation.tick_rules.decide` is the rule book, a pure
function of what the tick knows (e-stop latch, running run, staged runs, manual command,
battery, clock): it says which run ends, fails or starts and what to command, in the order of
precedence that :mod:`basestation.tick_rules` sets out. The manager applies the state
changes, makes the one exchange with the robot, and records what came back.

The values the tick and the API hand around (``ManualDrive``, ``EstopLatch``,
``AgentSnapshot``, ``TickDecision``, ...) belong to :mod:`basestation.tick_rules` and are
imported from there: this module uses them but does not re-export them. It offers
:class:`RunControl`, :class:`RunManager` and its own tuning constants.

One thing: the run manager, the state a tick changes and everything that changes it (runs, the
e-stop latch, manual control, the robot's exchange, what is recorded); its rule book is apart,
in basestation.tick_rules.
"""

from __future__ import annotations

import logging
import math
import sqlite3
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from typing import Protocol

from basestation.config import AgentConfig
from basestation.errors import RunConflict
from basestation.program import format_epoch
from basestation.provenance import (
    RunLinkTally,
    agent_facts,
    clock_facts,
    firmware_facts,
)
from basestation.robot import (
    Command,
    Direction,
    Robot,
    RobotIdentity,
    RobotLimits,
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
from basestation.system import cpu_temp_c
from basestation.telemetry.battery import BatteryFilter
from basestation.telemetry.laps import LapCounter
from basestation.telemetry.rail import Rail
from basestation.tick_rules import AgentSnapshot, EstopLatch, ManualDrive, TickDecision, decide
from basestation.writer import StoreWriter, WriterFull

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
# Link loss is counted over the last this many exchanges (5 s at 20 Hz).
LOSS_WINDOW = 100


class RunControl(Protocol):
    """What the API needs of the run manager: the :class:`RunManager` itself when the loop
    runs in the agent's process (tests), or
    :class:`basestation.loop_process.LoopProcess` when it runs in its own."""

    @property
    def snapshot(self) -> AgentSnapshot: ...

    @property
    def estop(self) -> EstopLatch | None: ...

    @property
    def rail_length_m(self) -> float: ...

    def manual(self, now_s: float) -> ManualDrive | None: ...

    def notify_runs_changed(self) -> None: ...

    def latch_estop(self, *, now_s: float, reason: str) -> tuple[EstopLatch, str | None]: ...

    def release_estop(self, *, now_s: float) -> bool: ...

    def drive_manually(
        self,
        *,
        now_s: float,
        user: str,
        velocity_mps: float,
        direction: Direction,
        ttl_s: float,
        force: bool,
    ) -> tuple[ManualDrive | None, str | None]: ...


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
        # What every run records of how it was made (basestation/provenance.py): this
        # agent and its robot's firmware as they are now, and the link over the running run.
        limits = getattr(robot, "limits", None)
        rail = getattr(robot, "rail", None)
        identity = getattr(robot, "identity", None)
        self.agent_facts = agent_facts(
            config,
            limits=limits if isinstance(limits, RobotLimits) else None,
            rail=rail if isinstance(rail, Rail) else None,
        )
        self.firmware_facts = firmware_facts(
            identity if isinstance(identity, RobotIdentity) else None
        )
        self._link_tally: RunLinkTally | None = None

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

    def shutdown(self, now_s: float, reason: str = "agent stopped during run") -> None:
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
                self._transition(self._active.id, RUNNING, INTERRUPTED, reason, now_s)
                self._active = None
            self._follow_provenance(now_s)
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
                # The stop frame goes out while the store writes (fsync releases the GIL).
                self.wake()
                self.store.set_estop(since_s=now_s, reason=reason)
                logger.warning("e-stop latched: %s", reason)
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
            aborted = self._make_way_for_manual(now_s, user=user, force=force)
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

    def _make_way_for_manual(self, now_s: float, *, user: str, force: bool) -> str | None:
        """Free the robot for ``user``'s manual command (under ``_api_lock``): the conflicts
        of :meth:`drive_manually`, or the id of the run aborted with ``force``."""
        if self._estop is not None:
            raise RunConflict(
                "estop_latched",
                "the emergency stop is latched: release it (POST /stop/release) first",
            )
        running = self.store.running_run_id()
        if running is None:
            return None
        if not force:
            raise RunConflict(
                "robot_busy",
                f'run {running} holds the robot; send "force": true to abort it and take over',
            )
        return self._abort_running(now_s, f"aborted: {user} took manual control")

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
        decision = self._decide(now_s)
        while not self._apply(decision, now_s):
            # The store refused the start (the run was withdrawn a moment ago): decide again
            # without it, as if it had never been due.
            decision = self._decide(now_s)
        command = self._command(decision, now_s)
        telemetry = self._exchange(command, now_s)
        self._record_tick(decision, command, telemetry, now_s)
        self._follow_provenance(now_s)

    def _decide(self, now_s: float) -> TickDecision:
        snapshot = self.snapshot
        since_s = self._low_battery_since_s
        return decide(
            now_s=now_s,
            estop=self._estop,
            stop_frame_owed=self._estop_frame_owed,
            run=self._active,
            schedule=self._schedule,
            manual=self._manual,
            battery_v=snapshot.battery_v,
            battery_low=snapshot.battery_low,
            battery_low_for_s=0.0 if since_s is None else now_s - since_s,
            low_battery_v=self.config.low_battery_v,
            direction=self._direction,
            max_accel_mps2=self.config.max_accel_mps2,
        )

    def _apply(self, decision: TickDecision, now_s: float) -> bool:
        """Make the decision's state changes, in order with the samples (through the writer).
        False when the store refuses the run it starts: nothing after that is applied."""
        ended = decision.end
        if ended is not None:
            self._end_run(ended.run, ended.to_state, ended.reason, now_s)
        for record, reason in decision.fail:
            self._schedule.remove(record)
            self._transition(record.id, STAGED, FAILED, reason, now_s)
        start = decision.start
        if start is not None:
            self._schedule.remove(start.run)
            # Queued with the writer, the start is optimistic: should an HTTP thread have
            # cancelled the run a moment ago, the writer refuses its samples and the next
            # refresh lets go of it. A run starts once, so its samples begin at seq 1.
            if self._transition(start.run.id, STAGED, RUNNING, start.reason, now_s) is False:
                return False
            self._active = start.run
            self._next_seq = 1
            self._provenance_started(start.run.id, now_s)
        manual = decision.end_manual
        if manual is not None and self._take_manual(manual) is manual:
            session_id = manual.session_id
            self.writer.submit(lambda: self.store.manual_session_end(session_id, ended_at_s=now_s))
            run = decision.run
            logger.info(
                "manual control by %s ended: %s",
                manual.user,
                "e-stop latched" if run is None else f"run {run.id} starts",
            )
        return True

    def _command(self, decision: TickDecision, now_s: float) -> Command:
        self._direction = decision.direction
        if decision.stop:
            # The robot brakes by itself on the flag; our ramp restarts from zero after release.
            self._estop_frame_owed = False
            self._setpoint_signed_mps = 0.0
            command = Command(velocity_mps=0.0, direction=decision.direction, estop=True)
        else:
            command = self._slew(
                now_s,
                signed_velocity_mps(decision.commanded_mps, decision.direction),
                decision.accel_mps2,
            )
        self._last_tick_s = now_s
        return command

    def _exchange(self, command: Command, now_s: float) -> Telemetry | None:
        """One command frame out, one telemetry frame back, or None (counted as lost)."""
        telemetry: Telemetry | None
        try:
            telemetry = self.robot.exchange(command, now_s)
        except RobotLinkError as exc:
            # No frame, no sample: nothing is invented. The link age in /status shows it.
            logger.debug("no telemetry at %.3f: %s", now_s, exc)
            telemetry = None
        self._answered.append(telemetry is not None)
        return telemetry

    def _record_tick(
        self,
        decision: TickDecision,
        command: Command,
        telemetry: Telemetry | None,
        now_s: float,
    ) -> None:
        """Keep what the tick saw: the battery, the run's sample (finishing the run once its
        program is over and the robot has stopped), and the snapshot for /status."""
        run = decision.run
        tally = self._link_tally
        if tally is not None and run is not None and run.id == tally.run_id:
            tally.add(telemetry)
        if telemetry is not None:
            # 0 V is the robot's "not measured yet" (before its first ADC reading after a
            # reset, docs/protocol.md): no real pack reads 0 V, and a median must not take it.
            if math.isfinite(telemetry.battery_v) and telemetry.battery_v > 0:
                self._battery.add(telemetry.battery_v)
            if run is not None:
                self._record(run, now_s, decision.segment, decision.commanded_mps, telemetry)
                program_over = now_s >= run.spec.start_at_s + run.spec.program_duration_s
                if (
                    self._active is not None
                    and program_over
                    and telemetry.velocity_mps < STOPPED_BELOW_MPS
                ):
                    self._end_run(run, COMPLETED, "program finished", now_s)

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

    # -- provenance ------------------------------------------------------------------------------

    def _provenance_started(self, run_id: str, now_s: float) -> None:
        """Record how the run is made as it starts (in order with its samples)."""
        self._link_tally = RunLinkTally(run_id)
        started = {
            "at": format_epoch(now_s),
            "agent": self.agent_facts,
            "firmware": self.firmware_facts,
            "clock": clock_facts(),
        }
        self.writer.submit(lambda: self.store.run_provenance_set(run_id, "started", started))

    def _follow_provenance(self, now_s: float) -> None:
        """Once the run whose link is tallied no longer holds the robot (ended here, or by an
        HTTP thread: abort, e-stop), record its end: the clock, and the link over the run."""
        tally = self._link_tally
        if tally is None or (self._active is not None and self._active.id == tally.run_id):
            return
        self._link_tally = None
        ended = {
            "at": format_epoch(now_s),
            "clock": clock_facts(),
            "link": tally.to_json_dict(),
            # The Pi's temperature as the run ends (its heaviest time: the robot's self-check
            # tracks it over the months).
            "cpu_temp_c": cpu_temp_c(self.config.cpu_temp_path),
        }
        run_id = tally.run_id
        self.writer.submit(lambda: self.store.run_provenance_set(run_id, "ended", ended))

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

    def _end_run(self, run: RunRecord, to_state: str, reason: str, now_s: float) -> None:
        """End the running run; the following ticks ramp the robot to zero unless another run
        or a manual command takes it."""
        self._transition(run.id, RUNNING, to_state, reason, now_s)
        self._active = None
