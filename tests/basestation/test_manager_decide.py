"""The tick's decision step, rule by rule: the precedence of ``basestation/tick_rules.py``'s
module docstring as a table, one row per rule and per combination that matters."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from basestation.program import parse_run_body
from basestation.robot import Direction
from basestation.runtime import AgentRuntime
from basestation.store import ABORTED, CANCELLED, COMPLETED, STAGED, RunRecord
from basestation.tick_rules import (
    LOW_BATTERY_HOLD_S,
    EstopLatch,
    ManualDrive,
    TickDecision,
    decide,
)
from tests.basestation.conftest import RecordingRobot, run_body

T0 = 1_900_000_000.0  # start of the run under test
MAX_ACCEL_MPS2 = 1.0  # the agent's limit
RUN_ACCEL_MPS2 = 0.4  # the run's own, gentler
LOW_BATTERY_V = 50.0


def _run(run_id: str, start_s: float, *, window_s: float = 10.0) -> RunRecord:
    """A running or staged run: 0.5 m/s cw for 3 s, then 0.8 m/s ccw for 3 s."""
    spec = parse_run_body(run_body(start_s, window_s=window_s, max_accel_mps2=RUN_ACCEL_MPS2))
    return RunRecord(
        id=run_id,
        spec=spec,
        body=spec.canonical_json(),
        state=STAGED,
        reason=None,
        created_at_s=start_s - 60.0,
        updated_at_s=start_s - 60.0,
        started_at_s=None,
        ended_at_s=None,
    )


RUN = _run("run", T0)
DUE = _run("due", T0)
PASSED = _run("passed", T0 - 20.0, window_s=10.0)  # its window closed at T0 - 10
LATER = _run("later", T0 + 100.0)
ESTOP = EstopLatch(since_s=T0 - 5.0, reason="cable")
MANUAL = ManualDrive(
    user="admin",
    velocity_mps=0.3,
    direction="ccw",
    session_started_at_s=T0 - 10.0,
    expires_at_s=T0 + 5.0,  # in force at T0 + 1
    session_id=7,
)


@dataclass(frozen=True)
class Case:
    """One row: what the tick knows (``now_s`` etc.) and what it must decide."""

    now_s: float = T0 + 1.0
    estop: EstopLatch | None = None
    stop_frame_owed: bool = False
    run: RunRecord | None = None
    schedule: tuple[RunRecord, ...] = ()
    manual: ManualDrive | None = None
    battery_v: float | None = 55.0
    battery_low: bool = False
    battery_low_for_s: float = 0.0
    last_direction: Direction = "cw"
    # Expected.
    end: tuple[str, str, str] | None = None  # run id, state, words in the reason
    fail: tuple[tuple[str, str], ...] = ()  # run id, words in the reason
    start: tuple[str, str] | None = None  # run id, reason
    end_manual: bool = False
    holder: str | None = None  # the run holding the robot afterwards
    stop: bool = False
    segment: int | None = None
    commanded_mps: float = 0.0
    direction: Direction = "cw"
    accel_mps2: float = MAX_ACCEL_MPS2


CASES = {
    # 4. Nothing: velocity 0, the last direction kept, no change.
    "nothing commands zero": Case(),
    "nothing keeps the last direction": Case(last_direction="ccw", direction="ccw"),
    "a run due later is not started": Case(schedule=(LATER,)),
    # 1. The e-stop latch.
    "e-stop alone sends the stop flag": Case(estop=ESTOP, stop=True),
    "e-stop aborts the running run": Case(
        estop=ESTOP, run=RUN, end=("run", ABORTED, "emergency stop: cable"), stop=True
    ),
    "e-stop ends manual control": Case(estop=ESTOP, manual=MANUAL, end_manual=True, stop=True),
    "e-stop keeps a due run staged": Case(estop=ESTOP, schedule=(DUE,), stop=True),
    "e-stop fails a run whose window passed": Case(
        estop=ESTOP,
        schedule=(PASSED, DUE),
        fail=(("passed", "while the emergency stop was latched"),),
        stop=True,
    ),
    "e-stop goes before the end of the window": Case(
        now_s=T0 + 10.0,
        estop=ESTOP,
        run=RUN,
        end=("run", ABORTED, "emergency stop"),
        stop=True,
    ),
    "a stop owed after release goes out once, manual keeps its command": Case(
        stop_frame_owed=True,
        manual=MANUAL,
        stop=True,
        commanded_mps=0.3,
        direction="ccw",
    ),
    # 2. The run's program, inside its booked window only.
    "the running run's program is commanded at its own acceleration": Case(
        run=RUN,
        holder="run",
        segment=0,
        commanded_mps=0.5,
        direction="cw",
        accel_mps2=RUN_ACCEL_MPS2,
    ),
    "the second segment": Case(
        now_s=T0 + 4.0,
        run=RUN,
        holder="run",
        segment=1,
        commanded_mps=0.8,
        direction="ccw",
        accel_mps2=RUN_ACCEL_MPS2,
    ),
    "before its window (clock stepped back) the run holds the robot at zero": Case(
        now_s=T0 - 1.0,
        run=RUN,
        last_direction="ccw",
        holder="run",
        direction="ccw",
        accel_mps2=RUN_ACCEL_MPS2,
    ),
    "after the program, inside the window, zero in the last direction": Case(
        now_s=T0 + 8.0, run=RUN, holder="run", direction="ccw", accel_mps2=RUN_ACCEL_MPS2
    ),
    "the end of the window finishes the run": Case(
        now_s=T0 + 10.0,
        run=RUN,
        end=("run", COMPLETED, "booked window ended"),
    ),
    "the end of the window goes before a low battery": Case(
        now_s=T0 + 10.0,
        run=RUN,
        battery_v=45.0,
        battery_low=True,
        battery_low_for_s=LOW_BATTERY_HOLD_S,
        end=("run", COMPLETED, "booked window ended"),
    ),
    "a brief low battery does not abort the run": Case(
        run=RUN,
        battery_v=45.0,
        battery_low=True,
        battery_low_for_s=LOW_BATTERY_HOLD_S - 0.05,
        holder="run",
        segment=0,
        commanded_mps=0.5,
        accel_mps2=RUN_ACCEL_MPS2,
    ),
    "a battery held low aborts the run": Case(
        run=RUN,
        battery_v=45.0,
        battery_low=True,
        battery_low_for_s=LOW_BATTERY_HOLD_S,
        end=("run", ABORTED, "battery low: 45.0 V, below 50 V"),
    ),
    "a due run starts": Case(
        now_s=T0 + 0.5,
        schedule=(DUE, LATER),
        start=("due", "started"),
        holder="due",
        segment=0,
        commanded_mps=0.5,
        accel_mps2=RUN_ACCEL_MPS2,
    ),
    "a late run starts and says so": Case(
        now_s=T0 + 2.5,
        schedule=(DUE,),
        start=("due", "started 2.5 s late"),
        holder="due",
        segment=0,
        commanded_mps=0.5,
        accel_mps2=RUN_ACCEL_MPS2,
    ),
    "a run whose window passed unseen fails and the next due one starts": Case(
        now_s=T0 + 0.5,
        schedule=(PASSED, DUE),
        fail=(("passed", "while the agent was not running"),),
        start=("due", "started"),
        holder="due",
        segment=0,
        commanded_mps=0.5,
        accel_mps2=RUN_ACCEL_MPS2,
    ),
    "a run due on a low battery fails instead of starting": Case(
        schedule=(DUE,),
        battery_v=45.0,
        battery_low=True,
        fail=(("due", "not started: battery at 45.0 V, below 50 V"),),
    ),
    "a booked run takes the robot from manual control": Case(
        now_s=T0 + 0.5,
        schedule=(DUE,),
        manual=MANUAL,
        start=("due", "started"),
        end_manual=True,
        holder="due",
        segment=0,
        commanded_mps=0.5,
        accel_mps2=RUN_ACCEL_MPS2,
    ),
    "a running run goes before a manual command": Case(
        run=RUN,
        manual=MANUAL,
        end_manual=True,
        holder="run",
        segment=0,
        commanded_mps=0.5,
        accel_mps2=RUN_ACCEL_MPS2,
    ),
    # 3. The manual command, until its time-to-live.
    "manual command in force": Case(manual=MANUAL, commanded_mps=0.3, direction="ccw"),
    "manual command with a run due later": Case(
        manual=MANUAL, schedule=(LATER,), commanded_mps=0.3, direction="ccw"
    ),
    "manual command past its time-to-live commands zero": Case(
        now_s=MANUAL.expires_at_s, manual=MANUAL
    ),
}


def _decide(case: Case) -> TickDecision:
    return decide(
        now_s=case.now_s,
        estop=case.estop,
        stop_frame_owed=case.stop_frame_owed,
        run=case.run,
        schedule=case.schedule,
        manual=case.manual,
        battery_v=case.battery_v,
        battery_low=case.battery_low,
        battery_low_for_s=case.battery_low_for_s,
        low_battery_v=LOW_BATTERY_V,
        direction=case.last_direction,
        max_accel_mps2=MAX_ACCEL_MPS2,
    )


@pytest.mark.parametrize("case", CASES.values(), ids=CASES.keys())
def test_the_decision_follows_the_precedence_rules(case: Case) -> None:
    decision = _decide(case)

    if case.end is None:
        assert decision.end is None
    else:
        assert decision.end is not None
        run_id, state, words = case.end
        assert (decision.end.run.id, decision.end.to_state) == (run_id, state)
        assert words in decision.end.reason
    assert [record.id for record, _ in decision.fail] == [run_id for run_id, _ in case.fail]
    for (_, reason), (_, words) in zip(decision.fail, case.fail, strict=True):
        assert words in reason
    if case.start is None:
        assert decision.start is None
    else:
        assert decision.start is not None
        assert (decision.start.run.id, decision.start.reason) == case.start
    assert decision.end_manual is (case.manual if case.end_manual else None)
    assert (decision.run.id if decision.run is not None else None) == case.holder
    assert decision.stop is case.stop
    assert decision.segment == case.segment
    assert decision.commanded_mps == pytest.approx(case.commanded_mps)
    assert decision.direction == case.direction
    assert decision.accel_mps2 == pytest.approx(case.accel_mps2)


def test_the_decision_has_no_side_effects() -> None:
    schedule = [PASSED, DUE, LATER]
    case = Case(schedule=tuple(schedule), manual=MANUAL)
    first = decide(
        now_s=case.now_s,
        estop=None,
        stop_frame_owed=False,
        run=None,
        schedule=schedule,
        manual=MANUAL,
        battery_v=55.0,
        battery_low=False,
        battery_low_for_s=0.0,
        low_battery_v=LOW_BATTERY_V,
        direction="cw",
        max_accel_mps2=MAX_ACCEL_MPS2,
    )
    assert schedule == [PASSED, DUE, LATER]
    assert first == _decide(case)  # same inputs, same decision


def test_a_start_the_store_refuses_leaves_the_robot_to_the_manual_command(
    runtime: AgentRuntime, robot: RecordingRobot
) -> None:
    manager = runtime.manager
    spec = parse_run_body(run_body(T0, window_s=10.0))
    runtime.store.stage_run("withdrawn", spec, now_s=T0 - 60.0, admit=lambda _: None)
    manager.tick(T0 - 0.5)  # reads the schedule
    manager.drive_manually(
        now_s=T0 - 0.4, user="admin", velocity_mps=0.3, direction="ccw", ttl_s=5.0, force=False
    )
    # Withdrawn behind the manager's back (no change notice, no refresh due yet): the tick
    # decides to start it, the store refuses, and the tick decides again without it.
    assert runtime.store.transition(
        "withdrawn", from_states=[STAGED], to_state=CANCELLED, reason="test", now_s=T0 - 0.3
    )
    manager.tick(T0)
    record = runtime.store.get_run("withdrawn")
    assert record is not None
    assert record.state == CANCELLED
    assert manager.snapshot.current_run is None
    assert runtime.store.samples_after("withdrawn", 0, 10) == []
    manual = manager.manual(T0)
    assert manual is not None
    assert manual.user == "admin"
    command = robot.exchanges[-1][1]
    assert (command.direction, command.estop) == ("ccw", False)
    assert command.velocity_mps > 0
