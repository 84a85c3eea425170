"""The driver and the link against the simulator: the emulated RFM69 on the simulated air,
and the robot's own firmware core on the other end."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import replace

import pytest

from basestation.protocol import (
    COMMAND_FRAME_SIZE,
    FixQuality,
    TelemetryStatus,
)
from basestation.radio import RFM69, RadioError, RadioRobotLink, RadioSettings, RadioTelemetry
from basestation.radio.registers import REG_IRQFLAGS2
from basestation.radio.rfm69 import AIRTIME_WAKE_EARLY_S, DEFAULT_POLL_INTERVAL_S
from basestation.robot import Command, RobotLimits, RobotLinkError
from basestation.sim.channel import InProcessChannel
from basestation.sim.clock import FakeClock
from basestation.sim.config import RadioConfig, SimConfig
from basestation.sim.rfm69 import EmulatedRFM69
from basestation.sim.robot import SimulatedRobot
from basestation.telemetry import Rail
from tests.basestation.radio.test_rfm69 import DOCUMENTED_BS_REGISTERS

KEY_HEX = "000102030405060708090a0b0c0d0e0f"
OTHER_KEY_HEX = "f0e0d0c0b0a090807060504030201000"
TICK_S = 0.05


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock(0.0)


@pytest.fixture
def channel(clock: FakeClock) -> InProcessChannel:
    # No RSSI noise: the robot's +17 dBm minus 75 dB of path is exactly -58 dBm.
    return InProcessChannel(clock=clock, rssi_sigma_db=0.0)


def driver(channel: InProcessChannel, clock: FakeClock, **settings: object) -> RFM69:
    chip = EmulatedRFM69(channel=channel, clock=clock)
    radio = RFM69(chip, RadioSettings(**settings), clock=clock, sleep=clock.sleep)  # type: ignore[arg-type]
    radio.begin()
    return radio


# -- driver to driver ---------------------------------------------------------------------------


def test_begin_leaves_the_emulated_chip_with_the_documented_settings_listening(
    channel: InProcessChannel, clock: FakeClock
) -> None:
    radio = driver(channel, clock)
    chip = radio.spi
    assert isinstance(chip, EmulatedRFM69)
    for address, value in DOCUMENTED_BS_REGISTERS.items():
        assert chip.peek(address) == value, f"register 0x{address:02X}"
    assert chip.mode == "rx"
    assert clock.now_s < 0.001  # mode switches take the datasheet's microseconds


def test_a_frame_crosses_the_air_with_its_rssi(channel: InProcessChannel, clock: FakeClock) -> None:
    base = driver(channel, clock, node=1)
    robot = driver(channel, clock, node=2)
    frame = bytes([5, 2, 1, 0, 1, 1])
    start_s = clock.now_s
    base.send(frame)
    # PacketSent comes one airtime later: preamble 3 + sync 2 + frame 6 + CRC 2 bytes at
    # 55.555 kbit/s = 1.87 ms, plus the datasheet's microseconds of mode switching.
    assert 0.00187 < clock.now_s - start_s < 0.0025
    assert robot.receive(0.01) == (frame, -58.0)
    assert robot.receive(0.0) is None  # received once
    assert robot.spi.mode == "rx"  # type: ignore[attr-defined]


def test_the_answer_comes_back_the_other_way(channel: InProcessChannel, clock: FakeClock) -> None:
    base = driver(channel, clock, node=1)
    robot = driver(channel, clock, node=2, high_power=False)
    robot.send(bytes([3, 1, 2, 0]))
    assert base.receive(0.01) == (bytes([3, 1, 2, 0]), -62.0)  # +13 dBm from an RFM69W


def test_a_frame_for_another_node_is_filtered_by_the_chip(
    channel: InProcessChannel, clock: FakeClock
) -> None:
    base = driver(channel, clock, node=1)
    robot = driver(channel, clock, node=2)
    base.send(bytes([3, 7, 1, 0]))  # to node 7
    assert robot.receive(0.01) is None
    base.send(bytes([3, 255, 1, 0]))  # broadcast
    assert robot.receive(0.01) == (bytes([3, 255, 1, 0]), -58.0)


def test_aes_on_both_ends_carries_frames_and_a_wrong_key_hears_nothing(
    channel: InProcessChannel, clock: FakeClock
) -> None:
    key = bytes.fromhex(KEY_HEX)
    base = driver(channel, clock, node=1, aes_key=key)
    robot = driver(channel, clock, node=2, aes_key=key)
    stranger = driver(channel, clock, node=2, aes_key=bytes.fromhex(OTHER_KEY_HEX))
    plain = driver(channel, clock, node=2)
    frame = bytes([13, 2, 1, 0, 1, 1, 7, 0, 0xF4, 1, 1, 0, 0xF4, 1])
    base.send(frame)
    assert robot.receive(0.02) == (frame, -58.0)
    assert stranger.receive(0.0) is None
    assert plain.receive(0.0) is None
    assert base.spi.peek(0x3D) == 0x13  # type: ignore[attr-defined]


def test_the_dio0_pin_can_replace_polling_the_irq_flags(
    channel: InProcessChannel, clock: FakeClock
) -> None:
    chip = EmulatedRFM69(channel=channel, clock=clock)
    base = RFM69(chip, clock=clock, sleep=clock.sleep, dio0=lambda: chip.dio0)
    base.begin()
    robot = driver(channel, clock, node=2)
    base.send(bytes([3, 2, 1, 0]))  # PacketSent seen on DIO0
    assert robot.receive(0.01) == (bytes([3, 2, 1, 0]), -58.0)
    robot.send(bytes([3, 1, 2, 0]))
    assert base.receive(0.01) == (bytes([3, 1, 2, 0]), -58.0)  # PayloadReady on DIO0


def test_a_closed_spi_device_is_a_radio_error(channel: InProcessChannel, clock: FakeClock) -> None:
    radio = driver(channel, clock)
    radio.close()
    with pytest.raises(RadioError, match="SPI transfer failed"):
        radio.receive(0.0)


# -- the link to the simulated robot ------------------------------------------------------------


@pytest.fixture
def sim_config() -> SimConfig:
    return SimConfig(start_track_m=10.0)


@pytest.fixture
def sim_robot(channel: InProcessChannel, sim_config: SimConfig) -> Iterator[SimulatedRobot]:
    # No skip: without the firmware core these tests prove nothing, so they fail loudly.
    robot = SimulatedRobot(sim_config, channel=channel)
    yield robot
    robot.close()


@pytest.fixture
def link(channel: InProcessChannel, clock: FakeClock, sim_robot: SimulatedRobot) -> RadioRobotLink:
    return RadioRobotLink(driver(channel, clock, node=1), rail=Rail.default())


Answer = RadioTelemetry | RobotLinkError


def drive(
    link: RadioRobotLink, clock: FakeClock, command: Command, seconds: float, start_s: float
) -> list[Answer]:
    """One exchange per 20 Hz tick on absolute deadlines, as the control loop does."""
    answers: list[Answer] = []
    for k in range(round(seconds / TICK_S)):
        tick_s = start_s + k * TICK_S
        clock.set(max(clock.now_s, tick_s))
        try:
            answers.append(link.exchange(command, tick_s))
        except RobotLinkError as exc:
            answers.append(exc)
    return answers


def telemetry_of(answer: Answer) -> RadioTelemetry:
    assert isinstance(answer, RadioTelemetry), f"no telemetry: {answer}"
    return answer


def test_the_robot_firmware_answers_every_command_well_inside_a_tick(
    link: RadioRobotLink, clock: FakeClock, sim_robot: SimulatedRobot
) -> None:
    clock.set(1.0)  # the GPS has had time for a fix
    telemetry = link.exchange(Command(velocity_mps=0.0, direction="cw"), 1.0)
    # Command 3.0 ms + robot 2 ms + telemetry 5.5 ms on air, plus the chips' mode switches.
    assert 0.0105 < clock.now_s - 1.0 < 0.012
    assert telemetry.command_accepted
    assert telemetry.fix_quality is FixQuality.RTK_FIXED
    assert telemetry.position_known
    assert telemetry.track_m == pytest.approx(10.0, abs=0.1)
    assert telemetry.grid_id == "A2"  # 10 m from the north corner: bearing 26.6°
    assert telemetry.battery_v > 50.0
    assert telemetry.rssi_dbm == -58.0
    assert telemetry.robot_rssi_dbm == -58


def test_an_exchange_looks_for_each_frame_only_once_it_can_have_crossed_the_air(
    link: RadioRobotLink, clock: FakeClock, sim_robot: SimulatedRobot, monkeypatch
) -> None:
    """The driver sleeps through its command's airtime and the telemetry's before it polls
    (SPI reads cost the Pi's CPU, 50 exchanges a second), and is answered no later for it."""
    radio = link.radio
    assert isinstance(radio, RFM69)
    chip = radio.spi
    assert isinstance(chip, EmulatedRFM69)
    polls: list[float] = []
    xfer2 = chip.xfer2

    def counting(data: Sequence[int]) -> list[int]:
        if data[0] == REG_IRQFLAGS2:  # a read (bit 7 clear) of the flags polled for
            polls.append(clock.now_s)
        return xfer2(data)

    chip.xfer2 = counting  # type: ignore[method-assign]

    def exchange(at_s: float) -> tuple[list[float], float]:
        polls.clear()
        clock.set(at_s)
        assert link.exchange(Command(velocity_mps=0.0, direction="cw"), at_s).command_accepted
        return list(polls), clock.now_s - at_s

    quiet, quiet_s = exchange(1.0)
    command_s = radio.airtime_s(COMMAND_FRAME_SIZE)
    # Nothing is polled for before the command can have been sent (the one look at 1.0 s
    # is the FIFO emptied of a stale frame, before sending).
    assert not [t for t in quiet if 1.0 < t < 1.0 + command_s - AIRTIME_WAKE_EARLY_S], quiet
    # The same exchange from a driver that polls from the start, as it did before.
    monkeypatch.setattr(radio, "airtime_s", lambda frame_len: 0.0)
    eager, eager_s = exchange(2.0)
    assert 2 * len(quiet) <= len(eager), (len(quiet), len(eager))
    # Answered as soon: within a poll of the eager driver, well inside a tick.
    assert quiet_s <= eager_s + DEFAULT_POLL_INTERVAL_S
    assert 0.0105 < quiet_s < 0.012


def test_the_robot_drives_where_it_is_told_and_the_link_follows_it(
    link: RadioRobotLink, clock: FakeClock, sim_robot: SimulatedRobot
) -> None:
    answers = drive(link, clock, Command(velocity_mps=1.0, direction="cw"), 10.0, 1.0)
    assert all(not isinstance(a, Exception) for a in answers)
    last = link.last_telemetry
    assert last is not None
    assert last.velocity_mps == pytest.approx(1.0, abs=0.05)
    assert last.direction == "cw"
    assert last.track_m == pytest.approx(sim_robot.track_m, abs=0.3)  # GPS lag and noise
    assert last.track_m > 15.0
    stats = link.stats(clock.now_s)
    assert (stats.state, stats.loss_pct, stats.replies_missing) == ("up", 0.0, 0)
    assert stats.frames_sent == len(answers) == 200


def test_an_e_stop_latches_on_the_robot_and_the_release_opens_it(
    link: RadioRobotLink, clock: FakeClock, sim_robot: SimulatedRobot
) -> None:
    drive(link, clock, Command(velocity_mps=0.5, direction="cw"), 1.0, 1.0)
    stopped = drive(link, clock, Command(velocity_mps=0.5, direction="cw", estop=True), 1.0, 2.0)
    assert telemetry_of(stopped[-1]).estop_latched
    assert sim_robot.status & TelemetryStatus.E_STOP_LATCHED
    assert sim_robot.velocity_mps == 0.0
    released = drive(link, clock, Command(velocity_mps=0.5, direction="cw"), 2.0, 3.0)
    assert not sim_robot.status & TelemetryStatus.E_STOP_LATCHED
    assert not telemetry_of(released[-1]).estop_latched
    assert telemetry_of(released[-1]).velocity_mps > 0.3
    assert not link.stats(clock.now_s).estop_release_pending


def test_a_cut_link_raises_and_goes_down_and_the_robot_stops_on_its_own(
    link: RadioRobotLink, clock: FakeClock, channel: InProcessChannel, sim_robot: SimulatedRobot
) -> None:
    drive(link, clock, Command(velocity_mps=1.0, direction="cw"), 3.0, 1.0)
    channel.cut()
    answers = drive(link, clock, Command(velocity_mps=1.0, direction="cw"), 3.0, 4.0)
    assert all(isinstance(a, RobotLinkError) for a in answers)
    stats = link.stats(clock.now_s)
    assert stats.state == "down"
    assert stats.loss_pct == pytest.approx(60.0)  # the last 60 of 100 commands
    assert sim_robot.velocity_mps == 0.0  # the firmware's dead-man
    assert sim_robot.status & TelemetryStatus.DEAD_MAN
    channel.restore()
    back = drive(link, clock, Command(velocity_mps=1.0, direction="cw"), 0.5, 7.0)
    assert not any(isinstance(a, Exception) for a in back)
    assert link.stats(clock.now_s).state == "up"


def test_a_lossy_channel_shows_in_the_loss_figure(clock: FakeClock, sim_config: SimConfig) -> None:
    channel = InProcessChannel(clock=clock, loss_probability=0.2, seed=3)
    robot = SimulatedRobot(sim_config, channel=channel)
    try:
        link = RadioRobotLink(driver(channel, clock), rail=Rail.default(), loss_window=400)
        answers = drive(link, clock, Command(velocity_mps=0.5, direction="cw"), 20.0, 1.0)
        lost = sum(isinstance(a, Exception) for a in answers)
        stats = link.stats(clock.now_s)
        # Either direction can lose the frame: about 1 - 0.8² = 36 % of the pairs.
        assert 0.25 < lost / len(answers) < 0.47
        assert stats.loss_pct == pytest.approx(100.0 * lost / len(answers))
        assert stats.state == "up"
    finally:
        robot.close()


def test_aes_on_both_ends_works_and_a_key_mismatch_is_silence(
    clock: FakeClock, channel: InProcessChannel, sim_config: SimConfig
) -> None:
    secret = replace(sim_config, radio=RadioConfig(aes_key_hex=KEY_HEX))
    robot = SimulatedRobot(secret, channel=channel)
    try:
        good = RadioRobotLink(
            driver(channel, clock, aes_key=bytes.fromhex(KEY_HEX)), rail=Rail.default()
        )
        answers = drive(good, clock, Command(velocity_mps=0.0, direction="cw"), 0.5, 1.0)
        assert not any(isinstance(a, Exception) for a in answers)
        wrong = RadioRobotLink(
            driver(channel, clock, aes_key=bytes.fromhex(OTHER_KEY_HEX)), rail=Rail.default()
        )
        with pytest.raises(RobotLinkError, match="no telemetry"):
            wrong.exchange(Command(velocity_mps=0.0, direction="cw"), clock.now_s)
    finally:
        robot.close()


def test_configure_gets_the_limits_the_firmware_applied(
    link: RadioRobotLink, clock: FakeClock, sim_robot: SimulatedRobot
) -> None:
    clock.set(1.0)
    limits = link.configure(max_velocity_mps=0.8, accel_mps2=0.4)
    assert limits.max_velocity_mps == pytest.approx(0.8)
    assert limits.max_accel_mps2 == pytest.approx(0.4)
    # The firmware reports the hard maximum compiled into it (robot_config.h: 4000 mm/s).
    assert limits.hard_max_velocity_mps == pytest.approx(4.0)


def test_configure_above_the_hard_maximum_is_applied_at_it_and_reported(
    link: RadioRobotLink, clock: FakeClock, sim_robot: SimulatedRobot
) -> None:
    clock.set(1.0)
    limits = link.configure(max_velocity_mps=6.0, accel_mps2=0.4)
    assert limits == RobotLimits(
        max_velocity_mps=4.0, max_accel_mps2=pytest.approx(0.4), hard_max_velocity_mps=4.0
    )


def test_a_robot_built_with_a_lower_hard_maximum_reports_it(
    clock: FakeClock, channel: InProcessChannel, sim_config: SimConfig
) -> None:
    slow = replace(sim_config, firmware={"hard_max_velocity_mm_s": 1500})
    robot = SimulatedRobot(slow, channel=channel)
    try:
        link = RadioRobotLink(driver(channel, clock, node=1), rail=Rail.default())
        clock.set(1.0)
        limits = link.configure(max_velocity_mps=2.0, accel_mps2=0.4)
        assert (limits.max_velocity_mps, limits.hard_max_velocity_mps) == (1.5, 1.5)
    finally:
        robot.close()
