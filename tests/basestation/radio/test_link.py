"""The radio robot link over the fake chip, with a scripted robot answering."""

from __future__ import annotations

import contextlib
import math
from pathlib import Path

import pytest

from basestation.config import AgentConfig
from basestation.manager import RunManager
from basestation.protocol import (
    COMMAND_FRAME_SIZE,
    CommandFlag,
    Direction,
    FixQuality,
    TelemetryFrame,
    TelemetryStatus,
    encode_telemetry,
)
from basestation.radio import RFM69, RadioRobotLink, RadioTelemetry
from basestation.radio.rfm69 import AIRTIME_WAKE_EARLY_S
from basestation.robot import Command, RobotLimits, RobotLinkError, Telemetry
from basestation.store import RunStore
from basestation.telemetry import Rail
from tests.basestation.conftest import TOKEN
from tests.basestation.radio.fakes import FakeChip, FakeClock, ScriptedRobot

CW = Command(velocity_mps=0.5, direction="cw")
STOP = Command(velocity_mps=0.0, direction="cw")


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def chip() -> FakeChip:
    return FakeChip()


@pytest.fixture
def rail() -> Rail:
    return Rail.default()


@pytest.fixture
def robot(chip: FakeChip, rail: Rail) -> ScriptedRobot:
    return ScriptedRobot(chip, rail, track_m=10.0)


@pytest.fixture
def link(chip: FakeChip, clock: FakeClock, rail: Rail, robot: ScriptedRobot) -> RadioRobotLink:
    radio = RFM69(chip, clock=clock, sleep=clock.sleep)
    radio.begin()
    return RadioRobotLink(radio, rail=rail)


def test_a_command_goes_out_numbered_and_its_telemetry_comes_back(
    link: RadioRobotLink, robot: ScriptedRobot, rail: Rail
) -> None:
    telemetry = link.exchange(CW, now_s=100.0)
    (sent,) = robot.commands
    assert (sent.seq, sent.velocity_mm_s, sent.direction, sent.flags, sent.ttl_ms) == (
        1,
        500,
        Direction.CW,
        CommandFlag(0),
        500,
    )
    assert (sent.to_node, sent.from_node) == (2, 1)

    assert isinstance(telemetry, Telemetry)
    assert isinstance(telemetry, RadioTelemetry)
    assert telemetry.velocity_mps == 0.5
    assert telemetry.direction == "cw"
    assert telemetry.battery_v == 60.0
    assert telemetry.track_m == pytest.approx(10.025, abs=0.02)  # GPS e7 rounding: ~1 cm
    assert telemetry.position_known
    assert telemetry.grid_id == rail.project(*rail.point_at(10.025)).grid_id == "A2"
    assert telemetry.lateral_m == pytest.approx(0.0, abs=0.02)
    assert telemetry.fix_quality is FixQuality.RTK_FIXED
    assert telemetry.satellites == 14
    assert (telemetry.command_seq, telemetry.echo_seq, telemetry.command_accepted) == (1, 1, True)
    assert telemetry.rssi_dbm == -55.0
    assert telemetry.robot_rssi_dbm == -48
    assert not telemetry.estop_latched

    stats = link.stats(now_s=100.02)
    assert (stats.state, stats.frames_sent, stats.replies_received, stats.loss_pct) == (
        "up",
        1,
        1,
        0.0,
    )
    assert stats.age_s == pytest.approx(0.02)
    assert stats.rssi_dbm == -55.0


def test_sequence_numbers_wrap_after_65535(chip: FakeChip, clock: FakeClock, rail: Rail) -> None:
    robot = ScriptedRobot(chip, rail)
    radio = RFM69(chip, clock=clock, sleep=clock.sleep)
    radio.begin()
    link = RadioRobotLink(radio, rail=rail, first_seq=65534)
    answers = [link.exchange(STOP, now_s=k * 0.05) for k in range(4)]
    assert [c.seq for c in robot.commands] == [65534, 65535, 0, 1]
    assert all(t.command_accepted for t in answers)


@pytest.mark.parametrize(
    ("velocity_mps", "direction", "wire_mm_s", "wire_direction"),
    [
        (0.0, "ccw", 0, Direction.CCW),
        (1.2345, "ccw", 1234, Direction.CCW),
        (25.0, "cw", 10_000, Direction.CW),  # the wire limit; the robot clamps further
        (-1.0, "cw", 0, Direction.CW),
        (math.nan, "cw", 0, Direction.CW),
    ],
)
def test_velocity_is_encoded_in_millimetres_per_second_within_the_wire_limit(
    link: RadioRobotLink,
    robot: ScriptedRobot,
    velocity_mps: float,
    direction: str,
    wire_mm_s: int,
    wire_direction: Direction,
) -> None:
    link.exchange(Command(velocity_mps=velocity_mps, direction=direction), now_s=0.0)  # type: ignore[arg-type]
    assert robot.commands[-1].velocity_mm_s == wire_mm_s
    assert robot.commands[-1].direction is wire_direction


def test_no_answer_is_a_robot_link_error_after_the_reply_timeout(
    link: RadioRobotLink, robot: ScriptedRobot, clock: FakeClock
) -> None:
    robot.answers = False
    start_s = clock.now_s
    with pytest.raises(RobotLinkError, match="no telemetry for command 1 within 25 ms"):
        link.exchange(CW, now_s=0.0)
    waited_s = clock.now_s - start_s
    # The command on air (no poll while it cannot have been sent), then the 25 ms wait.
    sent_s = link.radio.airtime_s(COMMAND_FRAME_SIZE) - AIRTIME_WAKE_EARLY_S
    assert 0.025 + sent_s <= waited_s < 0.027 + sent_s
    stats = link.stats(now_s=0.05)
    assert (stats.state, stats.frames_sent, stats.replies_missing, stats.loss_pct) == (
        "down",
        1,
        1,
        100.0,
    )
    assert stats.age_s is None


def test_loss_is_counted_over_a_sliding_window(
    chip: FakeChip, clock: FakeClock, rail: Rail, robot: ScriptedRobot
) -> None:
    radio = RFM69(chip, clock=clock, sleep=clock.sleep)
    radio.begin()
    link = RadioRobotLink(radio, rail=rail, loss_window=10)
    for k in range(10):
        robot.answers = k % 2 == 0
        with contextlib.suppress(RobotLinkError):
            link.exchange(STOP, now_s=k * 0.05)
    assert link.stats(now_s=0.5).loss_pct == 50.0
    robot.answers = True
    for k in range(10):
        link.exchange(STOP, now_s=1.0 + k * 0.05)
    stats = link.stats(now_s=1.5)
    assert stats.loss_pct == 0.0
    assert stats.window == 10
    assert (stats.frames_sent, stats.replies_received, stats.replies_missing) == (20, 15, 5)


def test_an_answer_that_does_not_echo_the_command_counts_as_a_lost_command(
    link: RadioRobotLink, robot: ScriptedRobot
) -> None:
    robot.echo_delta = -1  # the robot still holds the previous command
    telemetry = link.exchange(CW, now_s=0.0)
    assert not telemetry.command_accepted
    assert telemetry.command_seq == 1
    assert telemetry.echo_seq == 0
    stats = link.stats(now_s=0.0)
    assert stats.echo_mismatches == 1
    assert stats.loss_pct == 100.0
    assert stats.state == "up"  # the robot is there, it is the command that got lost


def test_a_late_frame_is_not_taken_for_the_next_answer(
    link: RadioRobotLink, robot: ScriptedRobot, chip: FakeChip
) -> None:
    link.exchange(STOP, now_s=0.0)
    # A late duplicate of an old answer is still waiting in the radio.
    chip.inject(_telemetry_echoing(0))
    telemetry = link.exchange(CW, now_s=0.05)
    assert telemetry.command_accepted
    assert telemetry.command_seq == 2


def _telemetry_echoing(echo_seq: int) -> bytes:
    return encode_telemetry(
        TelemetryFrame(
            seq=999,
            echo_seq=echo_seq,
            robot_clock_ms=0,
            velocity_mm_s=0,
            direction=Direction.CW,
            battery_10mv=0,
            lat_e7=0,
            lon_e7=0,
            fix_quality=FixQuality.NONE,
            satellites=0,
            status=TelemetryStatus(0),
            rssi_dbm=0,
        )
    )


def test_garbage_and_frames_for_others_are_skipped(
    link: RadioRobotLink, robot: ScriptedRobot
) -> None:
    from_elsewhere = bytearray(_telemetry_echoing(1))
    from_elsewhere[2] = 9  # from node 9, not the robot
    robot.before_answer = [bytes([3, 1, 2, 0]), bytes([2, 0xFF, 0xFF]), bytes(from_elsewhere)]
    telemetry = link.exchange(CW, now_s=0.0)
    assert telemetry.command_accepted
    assert telemetry.seq == 1
    assert link.stats(now_s=0.0).bad_frames == 3


def test_the_link_goes_down_a_second_after_the_last_answer(
    link: RadioRobotLink, robot: ScriptedRobot
) -> None:
    assert link.stats(now_s=0.0).state == "down"
    link.exchange(STOP, now_s=10.0)
    assert link.stats(now_s=11.0).state == "up"
    robot.answers = False
    with pytest.raises(RobotLinkError):
        link.exchange(STOP, now_s=11.0)
    stats = link.stats(now_s=11.01)
    assert stats.state == "down"
    assert stats.age_s == pytest.approx(1.01)


def test_gaps_in_the_robot_telemetry_numbers_are_counted(
    link: RadioRobotLink, robot: ScriptedRobot
) -> None:
    robot.seq_step = 3
    for k in range(4):
        link.exchange(STOP, now_s=k * 0.05)
    assert link.stats(now_s=0.2).telemetry_gaps == 6


def test_an_e_stop_is_flagged_and_its_release_is_sent_until_the_latch_opens(
    link: RadioRobotLink, robot: ScriptedRobot
) -> None:
    stopped = link.exchange(Command(velocity_mps=0.5, direction="cw", estop=True), now_s=0.0)
    assert robot.commands[-1].flags == CommandFlag.E_STOP
    assert robot.commands[-1].velocity_mm_s == 0
    assert stopped.estop_latched
    # The agent released its e-stop: the next command carries the release ...
    released = link.exchange(CW, now_s=0.05)
    assert robot.commands[-1].flags == CommandFlag.E_STOP_RELEASE
    assert not released.estop_latched
    # ... and once the robot reports the latch open, commands are plain again.
    link.exchange(CW, now_s=0.1)
    assert robot.commands[-1].flags == CommandFlag(0)
    assert not link.stats(now_s=0.1).estop_release_pending


def test_a_latch_the_agent_did_not_set_is_released_only_on_request(
    link: RadioRobotLink, robot: ScriptedRobot
) -> None:
    robot.latched = True  # kept in the robot's EEPROM across a restart
    robot.local_stop = True
    link.exchange(CW, now_s=0.0)
    assert robot.commands[-1].flags == CommandFlag(0)  # never released by itself
    link.release_estop()
    for k in range(3):
        telemetry = link.exchange(CW, now_s=0.05 * (k + 1))
        assert robot.commands[-1].flags == CommandFlag.E_STOP_RELEASE
        assert telemetry.estop_latched  # the local stop input is still open
    robot.local_stop = False
    assert not link.exchange(CW, now_s=1.0).estop_latched
    link.exchange(CW, now_s=1.05)
    assert robot.commands[-1].flags == CommandFlag(0)


def test_an_e_stop_cancels_a_pending_release(link: RadioRobotLink, robot: ScriptedRobot) -> None:
    link.release_estop()
    link.exchange(Command(velocity_mps=0.0, direction="cw", estop=True), now_s=0.0)
    assert robot.commands[-1].flags == CommandFlag.E_STOP


def test_without_a_fresh_fix_the_position_becomes_unknown(
    link: RadioRobotLink, robot: ScriptedRobot
) -> None:
    known = link.exchange(CW, now_s=0.0)
    robot.fix_quality = 0
    held = link.exchange(CW, now_s=1.9)
    assert held.fix_quality is FixQuality.NONE
    assert held.position_known  # the last fix is 1.9 s old: still the position
    assert held.track_m == known.track_m
    lost = link.exchange(CW, now_s=2.1)
    assert not lost.position_known
    assert lost.grid_id is None
    assert lost.lateral_m is None
    assert lost.track_m == known.track_m  # repeated: Telemetry.track_m cannot be empty
    robot.fix_quality = 5
    back = link.exchange(CW, now_s=2.2)
    assert back.position_known
    assert back.fix_quality is FixQuality.RTK_FLOAT
    assert back.track_m > known.track_m


def test_configure_returns_the_limits_the_robot_applied(link: RadioRobotLink) -> None:
    # The scripted robot answers with the older config frame: no hard maximum reported.
    assert link.configure(max_velocity_mps=5.0, accel_mps2=0.5) == RobotLimits(
        max_velocity_mps=3.0, max_accel_mps2=0.5, hard_max_velocity_mps=None
    )


def test_configure_reads_the_hard_maximum_from_the_acknowledgement(
    link: RadioRobotLink, robot: ScriptedRobot
) -> None:
    robot.hard_max_mm_s = 2500
    assert link.configure(max_velocity_mps=5.0, accel_mps2=0.5) == RobotLimits(
        max_velocity_mps=2.5, max_accel_mps2=0.5, hard_max_velocity_mps=2.5
    )


def test_a_radio_that_cannot_transmit_is_a_robot_link_error(
    link: RadioRobotLink, chip: FakeChip
) -> None:
    chip.tx_completes = False
    with pytest.raises(RobotLinkError, match="command 1 not sent: timed out"):
        link.exchange(CW, now_s=0.0)
    stats = link.stats(now_s=0.0)
    assert stats.send_errors == 1
    assert stats.loss_pct == 100.0


def test_the_run_manager_drives_the_robot_through_the_link(
    tmp_path: Path, link: RadioRobotLink, robot: ScriptedRobot
) -> None:
    """The agent's manager needs nothing new: answers become readings, silence does not."""
    config = AgentConfig(token=TOKEN, data_dir=tmp_path)
    store = RunStore(config.store_path)
    try:
        manager = RunManager(store=store, robot=link, config=config)
        for k in range(5):
            manager.tick(1000.0 + k * 0.05)
        assert manager.snapshot.link_errors == 0
        assert manager.snapshot.battery_v == 60.0
        robot.answers = False
        manager.tick(1000.25)
        assert manager.snapshot.link_errors == 1
        assert manager.snapshot.telemetry_at_s == 1000.2
        manager.shutdown(1000.3)  # logs the missing answer, does not raise
        assert all(c.velocity_mm_s == 0 for c in robot.commands)  # outside a run: zero
    finally:
        store.close()
