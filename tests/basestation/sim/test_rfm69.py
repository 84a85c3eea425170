"""The emulated RFM69 at the SPI register level: reset values, bursts, FIFO, modes, TX/RX."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from basestation.protocol import (
    CommandFrame,
    Direction,
    encode_command,
)
from basestation.sim.channel import InProcessChannel, airtime_s
from basestation.sim.clock import FakeClock
from basestation.sim.rfm69 import (
    INSTANT,
    IRQ1_MODE_READY,
    IRQ1_PLL_LOCK,
    IRQ1_RX_READY,
    IRQ1_TX_READY,
    IRQ2_CRC_OK,
    IRQ2_FIFO_FULL,
    IRQ2_FIFO_LEVEL,
    IRQ2_FIFO_NOT_EMPTY,
    IRQ2_FIFO_OVERRUN,
    IRQ2_PACKET_SENT,
    IRQ2_PAYLOAD_READY,
    EmulatedRFM69,
    ModeTimings,
    SpiDevice,
)
from tests.basestation.sim.driver import TinyDriver

COMMAND = encode_command(CommandFrame(seq=7, velocity_mm_s=1500, direction=Direction.CW))
KEY = bytes(range(16))


def read(chip: SpiDevice, address: int) -> int:
    return chip.xfer2([address, 0])[1]


def write(chip: SpiDevice, address: int, value: int) -> int:
    return chip.xfer2([address | 0x80, value])[1]


def pair(
    clock: FakeClock, *, keys: tuple[bytes | None, bytes | None] = (None, None), **air: float
) -> tuple[TinyDriver, TinyDriver, InProcessChannel]:
    """Base station (node 1) and robot-side (node 2) radios, set up as docs/protocol.md says."""
    channel = InProcessChannel(clock=clock, rssi_sigma_db=0.0, **air)  # type: ignore[arg-type]
    drivers = []
    for node, key in zip((1, 2), keys, strict=True):
        chip = EmulatedRFM69(channel=channel, name=f"node{node}")
        driver = TinyDriver(chip, clock=clock, sleep=clock.sleep, node=node, aes_key=key)
        driver.begin()
        drivers.append(driver)
    return drivers[0], drivers[1], channel


def test_registers_start_at_their_datasheet_reset_values(clock: FakeClock) -> None:
    chip = EmulatedRFM69(clock=clock)
    expected = {
        0x01: 0x04,  # sequencer on, standby
        0x02: 0x00,
        0x03: 0x1A,  # 4.8 kbit/s
        0x04: 0x0B,
        0x07: 0xE4,  # 915 MHz
        0x08: 0xC0,
        0x10: 0x24,  # RegVersion
        0x11: 0x9F,
        0x18: 0x08,  # reset, not the recommended 0x88
        0x19: 0x86,
        0x24: 0xFF,
        0x25: 0x00,
        0x26: 0x05,
        0x27: IRQ1_MODE_READY,
        0x28: 0x00,
        0x29: 0xFF,
        0x2D: 0x03,
        0x2E: 0x98,
        0x2F: 0x00,
        0x37: 0x10,
        0x38: 0x40,
        0x3C: 0x0F,
        0x3D: 0x02,
        0x6F: 0x00,
    }
    assert {address: read(chip, address) for address in expected} == expected
    assert chip.mode == "standby"


def test_write_answers_the_old_value_and_a_read_gives_the_new(clock: FakeClock) -> None:
    chip = EmulatedRFM69(clock=clock)
    assert chip.xfer2([0x2F | 0x80, 0xAA]) == [0x00, 0x00]
    assert chip.xfer2([0x2F | 0x80, 0x55]) == [0x00, 0xAA]
    assert chip.xfer2([0x2F, 0x00]) == [0x00, 0x55]


def test_bursts_auto_increment_the_address(clock: FakeClock) -> None:
    chip = EmulatedRFM69(clock=clock)
    chip.xfer2([0x3E | 0x80, *KEY])
    assert chip.xfer2([0x3E] + [0] * 16) == [0, *KEY]
    assert chip.xfer2([0x03, 0, 0, 0, 0]) == [0, 0x1A, 0x0B, 0x00, 0x52]


def test_read_only_registers_ignore_writes(clock: FakeClock) -> None:
    chip = EmulatedRFM69(clock=clock)
    assert write(chip, 0x10, 0x00) == 0x24
    assert read(chip, 0x10) == 0x24
    write(chip, 0x24, 0x00)
    assert read(chip, 0x24) == 0xFF


def test_fifo_pushes_and_pops_in_order_and_reports_its_level(clock: FakeClock) -> None:
    chip = EmulatedRFM69(clock=clock)
    write(chip, 0x3C, 0x04)  # FifoThreshold 4
    assert chip.xfer2([0x80, 1, 2, 3]) == [0, 0, 0, 0]  # FIFO writes answer zeros
    flags = read(chip, 0x28)
    assert flags & IRQ2_FIFO_NOT_EMPTY
    assert not flags & IRQ2_FIFO_LEVEL
    chip.xfer2([0x80, 4, 5])
    assert read(chip, 0x28) & IRQ2_FIFO_LEVEL  # 5 > 4
    assert chip.xfer2([0x00, 0, 0]) == [0, 1, 2]
    assert chip.xfer2([0x00, 0, 0, 0, 0]) == [0, 3, 4, 5, 0]  # empty FIFO reads 0
    assert read(chip, 0x28) == 0x00


def test_fifo_overflow_sets_overrun_and_writing_it_clears_the_fifo(clock: FakeClock) -> None:
    chip = EmulatedRFM69(clock=clock)
    chip.xfer2([0x80, *range(66)])
    flags = read(chip, 0x28)
    assert flags & IRQ2_FIFO_FULL
    assert not flags & IRQ2_FIFO_OVERRUN
    chip.xfer2([0x80, 0xEE])  # the 67th byte is lost
    assert read(chip, 0x28) & IRQ2_FIFO_OVERRUN
    assert chip.fifo == bytes(range(66))
    write(chip, 0x28, IRQ2_FIFO_OVERRUN)
    assert read(chip, 0x28) == 0x00
    assert chip.fifo == b""


def test_mode_ready_follows_the_start_up_time(clock: FakeClock) -> None:
    timings = ModeTimings()
    chip = EmulatedRFM69(clock=clock, timings=timings)
    write(chip, 0x01, 0x10)  # RX
    assert chip.mode == "rx"
    assert not read(chip, 0x27) & IRQ1_MODE_READY
    clock.advance(timings.transition_s(1, 4) + 1e-7)
    assert read(chip, 0x27) == IRQ1_MODE_READY | IRQ1_RX_READY | IRQ1_PLL_LOCK
    write(chip, 0x01, 0x00)  # sleep
    write(chip, 0x01, 0x0C)  # TX from sleep: oscillator + synthesizer + PA
    clock.advance(timings.oscillator_s + timings.synthesizer_s)
    assert not read(chip, 0x27) & IRQ1_MODE_READY
    clock.advance(timings.transmitter_s + 1e-7)
    assert read(chip, 0x27) == IRQ1_MODE_READY | IRQ1_TX_READY | IRQ1_PLL_LOCK
    write(chip, 0x01, 0x1C)  # reserved mode 111: ignored
    assert chip.mode == "tx"
    assert read(chip, 0x01) == 0x0C


@pytest.mark.parametrize(
    ("frame_len", "aes", "expected_ms"),
    [(14, False, 3.02), (31, False, 5.47), (12, False, 2.74), (66, False, 10.51),
     (14, True, 3.60), (31, True, 5.90)],
)  # fmt: skip
def test_airtime_is_the_protocol_table(frame_len: int, aes: bool, expected_ms: float) -> None:
    assert airtime_s(frame_len, aes=aes) * 1000 == pytest.approx(expected_ms, abs=0.005)


def test_tx_sets_packet_sent_one_airtime_after_tx_is_ready(clock: FakeClock) -> None:
    base, _, _ = pair(clock)
    chip = base.spi
    assert isinstance(chip, EmulatedRFM69)
    base.set_mode(0x04)
    chip.xfer2([0x80, *COMMAND])
    write(chip, 0x25, 0x00)  # DIO0 = PacketSent
    write(chip, 0x01, 0x0C)
    started = clock() + ModeTimings().transition_s(1, 3)
    assert chip.fifo == b""  # the packet engine took the frame
    clock.set(started + airtime_s(len(COMMAND)) - 1e-6)
    assert not read(chip, 0x28) & IRQ2_PACKET_SENT
    assert not chip.dio0
    clock.advance(2e-6)
    assert read(chip, 0x28) & IRQ2_PACKET_SENT
    assert chip.dio0
    write(chip, 0x01, 0x04)
    assert not read(chip, 0x28) & IRQ2_PACKET_SENT  # cleared when leaving TX


def test_rx_fills_the_fifo_and_sets_payload_ready_crc_ok_and_rssi(clock: FakeClock) -> None:
    base, robot_side, _ = pair(clock, path_loss_db=80.0)
    assert base.send(COMMAND)
    chip = robot_side.spi
    assert isinstance(chip, EmulatedRFM69)
    assert chip.dio0  # DIO0 mapping 01 in RX: PayloadReady
    assert read(chip, 0x28) & (IRQ2_PAYLOAD_READY | IRQ2_CRC_OK) == IRQ2_PAYLOAD_READY | IRQ2_CRC_OK
    assert read(chip, 0x24) == 2 * 63  # +17 dBm - 80 dB = -63 dBm
    assert robot_side.receive(0.001) == (COMMAND, -63)
    assert not chip.dio0
    assert read(chip, 0x28) & IRQ2_PAYLOAD_READY == 0  # cleared when the FIFO is empty


def test_a_packet_starting_before_rx_is_ready_is_missed(clock: FakeClock) -> None:
    base, robot_side, _ = pair(clock)
    robot_side.set_mode(0x04)
    base.set_mode(0x04)
    base.spi.xfer2([0x80, *COMMAND])
    write(base.spi, 0x01, 0x0C)  # TX starts in 115 us
    write(robot_side.spi, 0x01, 0x10)  # RX ready only in 210 us: misses the preamble
    clock.advance(0.01)
    assert robot_side.receive(0.001) is None


def test_a_corrupted_packet_is_dropped_when_crc_auto_clear_is_on(clock: FakeClock) -> None:
    base, robot_side, _ = pair(clock, loss_probability=1.0)
    assert base.send(COMMAND)
    assert robot_side.receive(0.005) is None
    assert isinstance(robot_side.spi, EmulatedRFM69)
    assert robot_side.spi.frames_dropped == 1


def test_a_corrupted_packet_reaches_the_fifo_without_crc_ok_when_auto_clear_is_off(
    clock: FakeClock,
) -> None:
    base, robot_side, _ = pair(clock, loss_probability=1.0)
    write(robot_side.spi, 0x37, 0x94 | 0x08)  # CrcAutoClearOff
    robot_side.start_rx()
    assert base.send(COMMAND)
    flags = read(robot_side.spi, 0x28)
    assert flags & IRQ2_PAYLOAD_READY
    assert not flags & IRQ2_CRC_OK


@pytest.mark.parametrize(
    ("keys", "heard"),
    [((KEY, KEY), True), ((KEY, bytes(16)), False), ((KEY, None), False), ((None, None), True)],
)
def test_aes_needs_the_same_key_at_both_ends(
    clock: FakeClock, keys: tuple[bytes | None, bytes | None], heard: bool
) -> None:
    base, robot_side, _ = pair(clock, keys=keys)
    assert base.send(COMMAND)
    received = robot_side.receive(0.005)
    assert (received is not None and received[0] == COMMAND) is heard


def test_address_filtering_takes_the_node_or_broadcast(clock: FakeClock) -> None:
    base, robot_side, _ = pair(clock)
    to_robot = encode_command(CommandFrame(seq=1, velocity_mm_s=0, direction=Direction.CW))
    to_other = encode_command(
        CommandFrame(seq=2, velocity_mm_s=0, direction=Direction.CW, to_node=9)
    )
    to_all = encode_command(
        CommandFrame(seq=3, velocity_mm_s=0, direction=Direction.CW, to_node=255)
    )
    received = []
    for frame in (to_robot, to_other, to_all):
        assert base.send(frame)
        answer = robot_side.receive(0.005)
        received.append(None if answer is None else answer[0])
    assert received == [to_robot, None, to_all]


def test_an_unread_packet_blocks_reception_until_the_fifo_is_read(clock: FakeClock) -> None:
    base, robot_side, _ = pair(clock)
    first = encode_command(CommandFrame(seq=1, velocity_mm_s=100, direction=Direction.CW))
    second = encode_command(CommandFrame(seq=2, velocity_mm_s=200, direction=Direction.CW))
    assert base.send(first)
    assert base.send(second)  # robot side still holds `first`: `second` is lost
    assert robot_side.receive(0.001) == (first, -58)
    assert robot_side.receive(0.005) is None
    assert base.send(second)  # AutoRxRestartOn: listening again once the FIFO was read
    assert robot_side.receive(0.005) == (second, -58)


def test_leaving_tx_early_truncates_the_packet_on_air(clock: FakeClock) -> None:
    base, robot_side, _ = pair(clock)
    base.set_mode(0x04)
    base.spi.xfer2([0x80, *COMMAND])
    write(base.spi, 0x01, 0x0C)
    clock.advance(0.001)  # a third of the packet is out
    write(base.spi, 0x01, 0x04)
    assert robot_side.receive(0.01) is None


def test_a_frame_shorter_than_its_length_byte_underruns_and_is_not_received(
    clock: FakeClock,
) -> None:
    base, robot_side, _ = pair(clock)
    base.set_mode(0x04)
    base.spi.xfer2([0x80, COMMAND[0]])  # length byte alone...
    write(base.spi, 0x01, 0x0C)  # ...and TX: the packet engine runs dry
    base.spi.xfer2([0x80, *COMMAND[1:]])
    assert robot_side.receive(0.01) is None


def test_rssi_start_measures_the_noise_floor_in_rx(clock: FakeClock) -> None:
    _, robot_side, _ = pair(clock)
    write(robot_side.spi, 0x23, 0x01)
    assert read(robot_side.spi, 0x23) & 0x02  # RssiDone
    assert 2 * 110 <= read(robot_side.spi, 0x24) <= 2 * 114


def test_a_length_above_payload_length_is_discarded(clock: FakeClock) -> None:
    base, robot_side, _ = pair(clock)
    write(robot_side.spi, 0x38, 10)  # accept at most 10 bytes after the length byte
    assert base.send(COMMAND)  # 13 after the length byte
    assert robot_side.receive(0.005) is None


def test_it_works_without_start_up_delays_and_with_the_real_clock() -> None:
    chip = EmulatedRFM69(timings=INSTANT)
    write(chip, 0x01, 0x10)
    assert read(chip, 0x27) & IRQ1_RX_READY
    chip.close()
    with pytest.raises(OSError, match="closed"):
        chip.xfer2([0x10, 0])


def test_bytes_outside_0_255_are_refused(clock: FakeClock) -> None:
    chip = EmulatedRFM69(clock=clock)
    with pytest.raises(ValueError, match=r"0\.\.255"):
        chip.xfer2([0x80, 256])
    assert chip.xfer2([]) == []


@settings(max_examples=300, deadline=None)
@given(
    transfers=st.lists(
        st.lists(st.integers(min_value=0, max_value=255), min_size=1, max_size=70), max_size=30
    ),
    steps_us=st.lists(st.integers(min_value=0, max_value=5000), min_size=30, max_size=30),
)
def test_arbitrary_spi_traffic_never_crashes_and_answers_in_kind(
    transfers: list[list[int]], steps_us: list[int]
) -> None:
    clock = FakeClock(0.0)
    channel = InProcessChannel(clock=clock)
    chip = EmulatedRFM69(channel=channel, seed=1)
    peer = EmulatedRFM69(channel=channel, seed=2)
    peer.xfer2([0x01 | 0x80, 0x10])
    for transfer, step_us in zip(transfers, steps_us, strict=False):
        answer = chip.xfer2(transfer)
        assert len(answer) == len(transfer)
        assert answer[0] == 0
        assert all(0 <= value <= 255 for value in answer)
        clock.advance(step_us * 1e-6)
        assert len(peer.fifo) <= 66
        _ = peer.dio0
    assert len(chip.fifo) <= 66


@settings(max_examples=200, deadline=None)
@given(data=st.binary(min_size=1, max_size=80))
def test_arbitrary_fifo_bytes_are_sent_or_refused_without_a_crash(data: bytes) -> None:
    clock = FakeClock(0.0)
    base, robot_side, _ = pair(clock)
    base.set_mode(0x04)
    base.spi.xfer2([0x80, *data])
    write(base.spi, 0x01, 0x0C)
    clock.advance(0.02)
    received = robot_side.receive(0.001)
    if received is not None:
        frame, _ = received
        assert frame == data[: data[0] + 1]
