"""Safety behaviour of the manager, driven by a fake clock: e-stop latch, manual drive with
its dead-man, the low-battery threshold, and motion only inside a run's booked window."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from dataclasses import replace
from typing import Any

import pytest
from flask import Flask

from basestation.app import create_app
from basestation.config import AgentConfig
from basestation.errors import RunConflict
from basestation.program import parse_run_body
from basestation.runtime import AgentRuntime, get_runtime
from basestation.tick_rules import LOW_BATTERY_HOLD_S
from tests.basestation.conftest import PERIOD_S, RecordingRobot, run_body

Drive = Callable[[float, float], float]
T0 = 1_900_000_000.0


def _stage(runtime: AgentRuntime, run_id: str, start_s: float, **kwargs: Any) -> None:
    spec = parse_run_body(run_body(start_s, **kwargs))
    runtime.store.stage_run(run_id, spec, now_s=start_s - 60.0, admit=lambda _: None)
    runtime.manager.notify_runs_changed()


def _state(runtime: AgentRuntime, run_id: str) -> tuple[str, str | None]:
    record = runtime.store.get_run(run_id)
    assert record is not None
    return record.state, record.reason


def _commands_from(robot: RecordingRobot, from_s: float) -> list[Any]:
    return [command for t, command, _, _ in robot.exchanges if t >= from_s]


def _drive_manually(runtime: AgentRuntime, now_s: float, **kwargs: Any) -> Any:
    arguments: dict[str, Any] = {
        "user": "admin",
        "velocity_mps": 0.5,
        "direction": "cw",
        "ttl_s": 1.0,
        "force": False,
    }
    arguments.update(kwargs)
    return runtime.manager.drive_manually(now_s=now_s, **arguments)


# -- e-stop ---------------------------------------------------------------------------------------


def test_the_first_tick_after_an_estop_sends_the_stop_flag_and_aborts_the_run(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    _stage(runtime, "run-1", T0 + 1.0)
    next_s = drive(T0, T0 + 3.0)
    latch, aborted = runtime.manager.latch_estop(now_s=next_s - 0.01, reason="test")
    assert aborted == "run-1"
    assert latch.reason == "test"
    count = runtime.store.sample_stats("run-1").count

    runtime.manager.tick(next_s)
    assert robot.exchanges[-1][1].estop
    assert robot.exchanges[-1][1].velocity_mps == 0.0
    drive(next_s + PERIOD_S, next_s + 3.0)
    assert all(command.estop for command in _commands_from(robot, next_s))
    assert robot.exchanges[-1][3] == 0.0  # the robot has stopped
    assert _state(runtime, "run-1") == ("aborted", "emergency stop: test")
    assert runtime.store.sample_stats("run-1").count == count


def test_latching_wakes_the_loop_and_the_urgent_call_sends_the_stop_frame_once(
    runtime: AgentRuntime, robot: RecordingRobot
) -> None:
    manager = runtime.manager
    wakes: list[bool] = []
    manager.on_wake = lambda: wakes.append(True)
    manager.tick(T0)
    manager.urgent(T0 + 0.01)  # nothing owed: no frame out of turn
    assert len(robot.exchanges) == 1
    manager.latch_estop(now_s=T0 + 0.02, reason="test")
    assert wakes == [True]
    manager.urgent(T0 + 0.021)
    assert len(robot.exchanges) == 2
    assert robot.exchanges[-1][1].estop
    manager.urgent(T0 + 0.03)  # sent already: the regular ticks carry the flag from here
    assert len(robot.exchanges) == 2
    manager.latch_estop(now_s=T0 + 0.04, reason="again")  # already latched: no new wake
    assert wakes == [True]


def test_the_urgent_call_starts_a_run_at_its_start_time_and_not_before(
    runtime: AgentRuntime, robot: RecordingRobot
) -> None:
    manager = runtime.manager
    _stage(runtime, "run-1", T0 + 0.03)
    manager.tick(T0)  # reads the schedule
    assert manager.next_start_s() == T0 + 0.03
    manager.urgent(T0 + 0.02)  # not yet: no frame out of turn
    assert len(robot.exchanges) == 1
    manager.urgent(T0 + 0.03)
    assert len(robot.exchanges) == 2
    assert robot.exchanges[-1][1].velocity_mps > 0  # the program's first command
    assert _state(runtime, "run-1")[0] == "running"
    assert manager.next_start_s() is None  # the robot is taken until this run ends


def test_the_estop_stays_latched_until_released_and_keeps_its_first_reason(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    runtime.manager.latch_estop(now_s=T0, reason="first")
    latch, _ = runtime.manager.latch_estop(now_s=T0 + 1, reason="second")
    assert (latch.since_s, latch.reason) == (T0, "first")
    next_s = drive(T0, T0 + 2.0)
    assert all(command.estop for command in _commands_from(robot, T0))

    assert runtime.manager.release_estop(now_s=next_s) is True
    assert runtime.manager.release_estop(now_s=next_s) is False
    drive(next_s, next_s + 0.5)
    assert not any(command.estop for command in _commands_from(robot, next_s))


def test_a_run_due_during_an_estop_waits_and_starts_late_after_release(
    runtime: AgentRuntime, drive: Drive
) -> None:
    runtime.manager.latch_estop(now_s=T0, reason="test")
    _stage(runtime, "run-1", T0 + 1.0)
    next_s = drive(T0, T0 + 3.0)
    assert _state(runtime, "run-1") == ("staged", None)
    runtime.manager.release_estop(now_s=next_s)
    drive(next_s, next_s + 0.2)
    state, reason = _state(runtime, "run-1")
    assert state == "running"
    assert reason is not None
    assert "late" in reason


def test_a_run_whose_window_passes_during_an_estop_fails_with_that_reason(
    runtime: AgentRuntime, drive: Drive
) -> None:
    runtime.manager.latch_estop(now_s=T0, reason="test")
    _stage(runtime, "run-1", T0 + 1.0, window_s=2.0, segments=[_segment(1.0)])
    drive(T0, T0 + 4.0)
    state, reason = _state(runtime, "run-1")
    assert state == "failed"
    assert reason is not None
    assert "emergency stop" in reason


def test_the_estop_latch_survives_a_restart_of_the_agent(
    agent_config: AgentConfig, robot: RecordingRobot
) -> None:
    first = create_app(agent_config, start_control_loop=False, robot=robot)
    get_runtime(first).manager.latch_estop(now_s=T0, reason="survives")
    get_runtime(first).close()

    second = create_app(agent_config, start_control_loop=False, robot=robot)
    try:
        manager = get_runtime(second).manager
        assert manager.estop is not None
        assert manager.estop.reason == "survives"
        manager.tick(T0 + 10.0)
        assert robot.exchanges[-1][1].estop
    finally:
        get_runtime(second).close()


# -- manual drive ----------------------------------------------------------------------------------


def _segment(duration_s: float, velocity_mps: float = 0.5) -> dict[str, Any]:
    return {"velocity_mps": velocity_mps, "direction": "cw", "duration_s": duration_s}


def test_manual_drive_moves_the_robot_until_its_time_to_live_runs_out(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    drive_, aborted = _drive_manually(runtime, T0, velocity_mps=0.5, direction="ccw", ttl_s=2.0)
    assert aborted is None
    assert drive_.expires_at_s == T0 + 2.0
    drive(T0, T0 + 5.0)
    held = [(t, true_mps) for t, _, _, true_mps in robot.exchanges if t < T0 + 2.0]
    assert held[-1][1] == pytest.approx(-0.5)  # ccw at full speed after the ramp
    # The dead-man: no renewal, so the robot is commanded down after 2 s and stops.
    after = _commands_from(robot, T0 + 2.0)
    assert after[0].velocity_mps < 0.5
    assert robot.exchanges[-1][3] == 0.0
    assert runtime.manager.manual(T0 + 5.0) is None
    # Nothing is recorded as a run; the usage log has the session.
    assert runtime.store.list_runs() == []
    (entry,) = runtime.store.usage_between(T0 - 1, T0 + 10)
    assert (entry.kind, entry.user, entry.start_s, entry.end_s) == ("manual", "admin", T0, T0 + 2)


def test_manual_commands_renew_the_dead_man_and_velocity_zero_ends_the_session(
    runtime: AgentRuntime, drive: Drive
) -> None:
    _drive_manually(runtime, T0, ttl_s=1.0)
    next_s = drive(T0, T0 + 0.8)
    _drive_manually(runtime, next_s, ttl_s=1.0)
    next_s = drive(next_s, next_s + 0.8)
    assert runtime.manager.manual(next_s) is not None
    assert _drive_manually(runtime, next_s, velocity_mps=0.0) == (None, None)
    assert runtime.manager.manual(next_s) is None
    (entry,) = runtime.store.usage_between(T0 - 1, T0 + 10)
    assert entry.start_s == T0
    assert entry.end_s == pytest.approx(next_s)


def test_manual_drive_is_refused_while_a_run_holds_the_robot(
    runtime: AgentRuntime, drive: Drive
) -> None:
    _stage(runtime, "run-1", T0 + 1.0)
    next_s = drive(T0, T0 + 2.0)
    with pytest.raises(RunConflict) as refused:
        _drive_manually(runtime, next_s)
    assert refused.value.kind == "robot_busy"
    assert _state(runtime, "run-1")[0] == "running"
    assert runtime.manager.manual(next_s) is None


def test_forced_manual_drive_aborts_the_run_and_takes_over(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    _stage(runtime, "run-1", T0 + 1.0)
    next_s = drive(T0, T0 + 2.0)
    manual, aborted = _drive_manually(
        runtime, next_s, user="carol", velocity_mps=0.2, direction="ccw", ttl_s=5.0, force=True
    )
    assert aborted == "run-1"
    assert manual is not None
    assert _state(runtime, "run-1") == ("aborted", "aborted: carol took manual control")
    drive(next_s, next_s + 3.0)
    assert robot.exchanges[-1][3] == pytest.approx(-0.2)


def test_manual_drive_is_refused_while_the_estop_is_latched(runtime: AgentRuntime) -> None:
    runtime.manager.latch_estop(now_s=T0, reason="test")
    with pytest.raises(RunConflict) as refused:
        _drive_manually(runtime, T0 + 1, force=True)
    assert refused.value.kind == "estop_latched"


def test_an_estop_ends_manual_drive(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    _drive_manually(runtime, T0, ttl_s=10.0)
    next_s = drive(T0, T0 + 1.0)
    runtime.manager.latch_estop(now_s=next_s, reason="test")
    runtime.manager.release_estop(now_s=next_s)
    drive(next_s, next_s + 1.0)
    assert runtime.manager.manual(next_s + 1.0) is None
    after = _commands_from(robot, next_s)
    # Latched and released before the next tick: the stop frame still goes out once.
    assert after[0].estop
    assert not any(command.estop for command in after[1:])
    assert all(command.velocity_mps == 0.0 for command in after)


def test_a_booked_run_takes_the_robot_from_manual_drive(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    _stage(runtime, "run-1", T0 + 1.0)
    _drive_manually(runtime, T0, velocity_mps=0.3, ttl_s=10.0)
    drive(T0, T0 + 2.0)
    assert _state(runtime, "run-1")[0] == "running"
    assert runtime.manager.manual(T0 + 2.0) is None
    sessions = [e for e in runtime.store.usage_between(T0 - 1, T0 + 20) if e.kind == "manual"]
    assert sessions[0].end_s == pytest.approx(T0 + 1.0)


# -- low battery -----------------------------------------------------------------------------------


@pytest.fixture
def low_battery_app(agent_config: AgentConfig, robot: RecordingRobot) -> Iterator[Flask]:
    # The simulated battery reads 60 V at rest and sags 0.4 V per m/s under way.
    app = create_app(
        replace(agent_config, low_battery_v=59.9), start_control_loop=False, robot=robot
    )
    yield app
    get_runtime(app).close()


def test_a_run_does_not_start_on_a_low_battery(
    agent_config: AgentConfig, robot: RecordingRobot
) -> None:
    app = create_app(
        replace(agent_config, low_battery_v=60.5), start_control_loop=False, robot=robot
    )
    runtime = get_runtime(app)
    try:
        _stage(runtime, "run-1", T0 + 1.0)
        for k in range(40):
            runtime.manager.tick(T0 + k * PERIOD_S)
        state, reason = _state(runtime, "run-1")
        assert state == "failed"
        assert reason is not None
        assert "battery" in reason
        assert "AGENT_LOW_BATTERY_V" in reason
        assert all(command.velocity_mps == 0.0 for _, command, _, _ in robot.exchanges)
    finally:
        runtime.close()


class JustResetRobot(RecordingRobot):
    """Reports 0 V, the protocol's "not measured yet", in every frame before ``measured_s``."""

    measured_s: float = 0.0
    zeros_sent: int = 0

    def exchange(self, command: Any, now_s: float) -> Any:
        telemetry = super().exchange(command, now_s)
        if now_s >= self.measured_s:
            return telemetry
        self.zeros_sent += 1
        return replace(telemetry, battery_v=0.0)


def test_not_measured_yet_is_neither_low_battery_nor_a_sample_of_0_v(
    agent_config: AgentConfig, robot: RecordingRobot
) -> None:
    # The robot resets during the run: 0 V from 2 s after the start, for 3 s — longer than
    # the hold after which a real low battery aborts the run.
    flaky = JustResetRobot(robot.inner)
    app = create_app(
        replace(agent_config, low_battery_v=50.0), start_control_loop=False, robot=flaky
    )
    runtime = get_runtime(app)
    try:
        _stage(runtime, "run-1", T0 + 1.0, window_s=30.0, segments=[_segment(6.0)])
        k = 0
        while T0 + k * PERIOD_S < T0 + 3.0:
            runtime.manager.tick(T0 + k * PERIOD_S)
            k += 1
        flaky.measured_s = T0 + 6.0
        while T0 + k * PERIOD_S < T0 + 9.0:
            runtime.manager.tick(T0 + k * PERIOD_S)
            k += 1
        state, reason = _state(runtime, "run-1")
        assert (state, reason) == ("completed", "program finished")
        assert flaky.zeros_sent == 60  # 3 s at 20 Hz
        runtime.manager.writer.flush()
        stored = runtime.store.samples_after("run-1", 0, 1000)
        assert len(stored) > 100
        assert min(s.battery_v for s in stored) > 55.0
        assert runtime.manager.snapshot.battery_v is not None
        assert runtime.manager.snapshot.battery_v > 55.0
    finally:
        runtime.close()


def test_a_running_run_is_aborted_when_the_battery_stays_low_and_the_robot_ramps_down(
    low_battery_app: Flask, robot: RecordingRobot
) -> None:
    runtime = get_runtime(low_battery_app)
    segments = [_segment(20.0, velocity_mps=1.0)]
    _stage(runtime, "run-1", T0 + 1.0, window_s=30.0, segments=segments)
    now_s = T0
    while now_s < T0 + 12.0:
        runtime.manager.tick(now_s)
        now_s += PERIOD_S
    state, reason = _state(runtime, "run-1")
    assert state == "aborted"
    assert reason is not None
    assert reason.startswith("battery low")
    record = runtime.store.get_run("run-1")
    assert record is not None
    assert record.ended_at_s is not None
    # Under way at 1 m/s the battery reads ~59.6 V: low from about 0.3 s after the start
    # (0.3 m/s of sag), aborted LOW_BATTERY_HOLD_S later, not at the first low reading.
    assert record.ended_at_s - (T0 + 1.0) >= LOW_BATTERY_HOLD_S
    assert record.ended_at_s - (T0 + 1.0) < LOW_BATTERY_HOLD_S + 1.5
    after = [true_mps for t, _, _, true_mps in robot.exchanges if t >= record.ended_at_s]
    assert after[-1] == 0.0
    steps = [abs(b - a) for a, b in itertools.pairwise(after)]
    assert max(steps) <= 1.0 * PERIOD_S + 1e-9  # ramped at the acceleration limit


def test_a_low_battery_threshold_of_zero_switches_the_check_off(
    agent_config: AgentConfig, robot: RecordingRobot
) -> None:
    app = create_app(
        replace(agent_config, low_battery_v=0.0), start_control_loop=False, robot=robot
    )
    runtime = get_runtime(app)
    try:
        _stage(runtime, "run-1", T0 + 0.5)
        for k in range(40):
            runtime.manager.tick(T0 + k * PERIOD_S)
        assert _state(runtime, "run-1")[0] == "running"
        assert runtime.manager.snapshot.battery_low is False
    finally:
        runtime.close()


# -- the booked window -----------------------------------------------------------------------------


def test_a_run_gets_no_motion_when_the_clock_steps_back_before_its_window(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    _stage(runtime, "run-1", T0 + 1.0)
    drive(T0, T0 + 2.0)
    assert _state(runtime, "run-1")[0] == "running"
    # NTP steps the clock back by a minute: the run is still running, but before its window.
    stepped_s = T0 - 60.0
    drive(stepped_s, stepped_s + 3.0)
    assert all(command.velocity_mps <= 0.5 for command in _commands_from(robot, stepped_s))
    commanded = [s.commanded_velocity_mps for s in runtime.store.samples_after("run-1", 0, 10**6)]
    assert commanded[-1] == 0.0
    assert robot.exchanges[-1][3] == 0.0
