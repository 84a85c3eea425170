"""The manager driven by a fake clock: no thread, every tick called by the test."""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import Any

import pytest

from basestation.program import parse_run_body
from basestation.runtime import AgentRuntime
from basestation.services import run_withdraw
from basestation.store import Sample
from tests.basestation.conftest import PERIOD_S, RecordingRobot, run_body

Drive = Callable[[float, float], float]
NOISE_MPS = 0.01
T0 = 1_900_000_000.0  # a fixed agent time; the manager never reads the real clock


def _stage(runtime: AgentRuntime, run_id: str, start_s: float, **kwargs: Any) -> None:
    spec = parse_run_body(run_body(start_s, **kwargs))
    runtime.store.stage_run(run_id, spec, now_s=start_s - 60.0, admit=lambda _: None)
    runtime.manager.notify_runs_changed()


def _samples(runtime: AgentRuntime, run_id: str) -> list[Sample]:
    return runtime.store.samples_after(run_id, 0, 100_000)


def _max_accel_mps2(exchanges: list[tuple[float, Any, Any, float]]) -> float:
    """The largest true acceleration between consecutive exchanges."""
    return max(
        abs(v1 - v0) / (t1 - t0) for (t0, *_, v0), (t1, *_, v1) in itertools.pairwise(exchanges)
    )


def _signed(sample: Sample) -> float:
    return sample.velocity_mps if sample.direction == "cw" else -sample.velocity_mps


def test_it_commands_zero_and_records_nothing_when_idle(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    drive(T0, T0 + 5.0)
    assert len(robot.exchanges) == 100
    assert all(command.velocity_mps == 0.0 for _, command, _, _ in robot.exchanges)
    assert all(true_mps == 0.0 for *_, true_mps in robot.exchanges)
    assert runtime.store.list_runs() == []
    assert runtime.manager.snapshot.current_run is None
    assert runtime.manager.snapshot.battery_v == pytest.approx(60.0, abs=0.1)


def test_it_commands_zero_before_the_start_of_a_staged_run(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    _stage(runtime, "run-1", T0 + 10.0)
    drive(T0, T0 + 10.0)
    assert all(command.velocity_mps == 0.0 for _, command, _, _ in robot.exchanges)
    record = runtime.store.get_run("run-1")
    assert record is not None
    assert record.state == "staged"
    assert _samples(runtime, "run-1") == []


def test_it_runs_a_two_segment_program_and_completes(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    start_s = T0 + 1.0
    _stage(runtime, "run-1", start_s)  # 0.5 m/s cw 3 s, then 0.8 m/s ccw 3 s, window 10 s
    drive(T0, start_s + 12.0)

    record = runtime.store.get_run("run-1")
    assert record is not None
    assert record.state == "completed"
    assert record.reason == "program finished"
    assert record.started_at_s == pytest.approx(start_s)
    # The program ends at 6 s; braking from 0.8 m/s at 1 m/s^2 takes 0.8 s more.
    assert record.ended_at_s is not None
    assert record.ended_at_s - start_s == pytest.approx(6.8, abs=0.15)

    samples = _samples(runtime, "run-1")
    assert [s.seq for s in samples] == list(range(1, len(samples) + 1))
    assert samples[0].t == pytest.approx(start_s)
    assert samples[-1].t == pytest.approx(record.ended_at_s)
    # One sample per tick while the run held the robot: nothing before the start, nothing
    # after completion.
    assert len(samples) == round((record.ended_at_s - start_s) / PERIOD_S) + 1

    for sample in samples:
        elapsed_s = sample.t - start_s
        if 0.5 + 0.1 <= elapsed_s < 3.0:  # after the 0.5 s ramp to 0.5 m/s
            assert sample.segment == 0
            assert sample.direction == "cw"
            assert sample.velocity_mps == pytest.approx(0.5, abs=0.05)
        elif 3.0 + 1.3 + 0.1 <= elapsed_s < 6.0:  # after the 1.3 s ramp from +0.5 to -0.8
            assert sample.segment == 1
            assert sample.direction == "ccw"
            assert sample.velocity_mps == pytest.approx(0.8, abs=0.05)
        elif elapsed_s >= 6.0 + 1e-9:
            assert sample.segment is None
            assert sample.commanded_velocity_mps == 0.0
    assert {s.commanded_velocity_mps for s in samples if s.segment == 0} == {0.5}
    assert {s.commanded_velocity_mps for s in samples if s.segment == 1} == {0.8}

    # The reversal passes through zero: where the reported direction flips, the two
    # speeds add up to no more than one tick of acceleration (plus the encoder noise).
    flips = [(a, b) for a, b in itertools.pairwise(samples) if a.direction != b.direction]
    assert len(flips) == 1
    a, b = flips[0]
    assert a.velocity_mps + b.velocity_mps <= 1.0 * PERIOD_S + 2 * NOISE_MPS

    # Acceleration never exceeds the limit: exactly on the true velocity, within the
    # noise on the measured one.
    assert _max_accel_mps2(robot.exchanges) <= 1.0 + 1e-9
    for s0, s1 in itertools.pairwise(samples):
        assert abs(_signed(s1) - _signed(s0)) <= 1.0 * (s1.t - s0.t) + 2 * NOISE_MPS

    # After completion the robot is told zero and stays put.
    assert runtime.manager.snapshot.current_run is None
    assert robot.exchanges[-1][1].velocity_mps == 0.0
    assert robot.exchanges[-1][3] == 0.0


def test_it_ramps_no_faster_than_the_runs_own_acceleration_limit(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    start_s = T0 + 1.0
    _stage(runtime, "run-1", start_s, max_accel_mps2=0.25)
    drive(T0, start_s + 10.0)
    assert _max_accel_mps2(robot.exchanges) == pytest.approx(0.25)
    samples = _samples(runtime, "run-1")
    # At 0.25 m/s^2 the 0.5 m/s of the first segment takes 2 s.
    at_one_s = next(s for s in samples if s.t >= start_s + 1.0)
    assert at_one_s.velocity_mps == pytest.approx(0.25, abs=0.03)


def test_it_completes_at_the_end_of_the_window_even_if_the_robot_still_moves(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    start_s = T0 + 1.0
    # 1 m/s for the whole window: no time left to brake inside it.
    segments = [{"velocity_mps": 1.0, "direction": "cw", "duration_s": 4.0}]
    _stage(runtime, "run-1", start_s, window_s=4.0, segments=segments)
    drive(T0, start_s + 6.0)
    record = runtime.store.get_run("run-1")
    assert record is not None
    assert record.state == "completed"
    assert record.reason is not None
    assert "window ended" in record.reason
    assert record.ended_at_s == pytest.approx(start_s + 4.0)
    assert max(s.t for s in _samples(runtime, "run-1")) < start_s + 4.0
    # Outside the window the robot is commanded to zero at once.
    after = [cmd.velocity_mps for t, cmd, _, _ in robot.exchanges if t >= start_s + 4.0]
    assert after[0] < 1.0
    assert after == sorted(after, reverse=True)
    assert after[-1] == 0.0


def test_it_runs_back_to_back_runs_with_their_own_sequences(
    runtime: AgentRuntime, drive: Drive
) -> None:
    _stage(runtime, "run-1", T0 + 1.0)
    _stage(runtime, "run-2", T0 + 11.0)
    drive(T0, T0 + 22.0)
    for run_id in ("run-1", "run-2"):
        record = runtime.store.get_run(run_id)
        assert record is not None
        assert record.state == "completed"
        samples = _samples(runtime, run_id)
        assert [s.seq for s in samples] == list(range(1, len(samples) + 1))


def test_it_marks_a_run_failed_when_its_window_passed_unseen(
    runtime: AgentRuntime, drive: Drive
) -> None:
    _stage(runtime, "run-1", T0 - 20.0)  # ended at T0 - 10: the agent was not running
    drive(T0, T0 + 1.0)
    record = runtime.store.get_run("run-1")
    assert record is not None
    assert record.state == "failed"
    assert record.reason is not None
    assert "window passed" in record.reason


def test_it_starts_a_late_staged_run_at_once_and_says_so(
    runtime: AgentRuntime, drive: Drive
) -> None:
    _stage(runtime, "run-1", T0 - 2.0)
    drive(T0, T0 + 0.1)
    record = runtime.store.get_run("run-1")
    assert record is not None
    assert record.state == "running"
    assert record.reason == "started 2.0 s late"


def test_it_stops_recording_and_ramps_down_when_a_run_is_aborted(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    start_s = T0 + 1.0
    _stage(runtime, "run-1", start_s)
    next_s = drive(T0, start_s + 2.0)
    run_withdraw(store=runtime.store, manager=runtime.manager, run_id="run-1", now_s=next_s)
    count = len(_samples(runtime, "run-1"))
    drive(next_s, next_s + 2.0)
    assert len(_samples(runtime, "run-1")) == count
    record = runtime.store.get_run("run-1")
    assert record is not None
    assert record.state == "aborted"
    after = [exchange for exchange in robot.exchanges if exchange[0] >= next_s]
    assert after[0][3] > 0.4
    assert after[-1][3] == 0.0
    assert _max_accel_mps2(after) <= 1.0 + 1e-9


def test_it_interrupts_the_current_run_on_shutdown(
    runtime: AgentRuntime, robot: RecordingRobot, drive: Drive
) -> None:
    start_s = T0 + 1.0
    _stage(runtime, "run-1", start_s)
    next_s = drive(T0, start_s + 2.0)
    runtime.manager.shutdown(next_s)
    record = runtime.store.get_run("run-1")
    assert record is not None
    assert record.state == "interrupted"
    assert record.reason == "agent stopped during run"
    assert robot.exchanges[-1][1].velocity_mps == 0.0
    assert len(_samples(runtime, "run-1")) == 40
