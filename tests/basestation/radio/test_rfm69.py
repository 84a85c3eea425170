"""The RFM69 driver against a register-recording fake chip (no hardware, no real waits)."""

from __future__ import annotations

import os

import pytest

from basestation.radio import RFM69, RadioError, RadioSettings, open_spidev, parse_aes_key
from tests.basestation.radio.fakes import FakeChip, FakeClock

KEY = bytes(range(16))

# docs/protocol.md §1, copied from the document on purpose (not from the driver's
# constants): the chip must end up holding exactly these values.
DOCUMENTED_BS_REGISTERS = {
    0x02: 0x00,  # RegDataModul
    0x03: 0x02,  # RegBitrateMsb
    0x04: 0x40,  # RegBitrateLsb
    0x05: 0x03,  # RegFdevMsb
    0x06: 0x33,  # RegFdevLsb
    0x07: 0x6C,  # RegFrfMsb
    0x08: 0x40,  # RegFrfMid
    0x09: 0x00,  # RegFrfLsb
    0x11: 0x7F,  # RegPaLevel (RFM69HW)
    0x18: 0x88,  # RegLna
    0x19: 0x42,  # RegRxBw
    0x25: 0x40,  # RegDioMapping1 in RX
    0x26: 0x07,  # RegDioMapping2
    0x29: 0xDC,  # RegRssiThresh
    0x2C: 0x00,  # RegPreambleMsb
    0x2D: 0x03,  # RegPreambleLsb
    0x2E: 0x88,  # RegSyncConfig
    0x2F: 0x2D,  # RegSyncValue1
    0x30: 0x64,  # RegSyncValue2: network 100
    0x37: 0x94,  # RegPacketConfig1
    0x38: 0x42,  # RegPayloadLength
    0x39: 0x01,  # RegNodeAdrs: BS
    0x3A: 0xFF,  # RegBroadcastAdrs
    0x3C: 0x8F,  # RegFifoThresh
    0x3D: 0x12,  # RegPacketConfig2, AES off
    0x6F: 0x30,  # RegTestDagc
}


def radio_on(
    chip: FakeChip, clock: FakeClock, settings: RadioSettings | None = None, **kwargs: object
) -> RFM69:
    return RFM69(chip, settings, clock=clock, sleep=clock.sleep, **kwargs)  # type: ignore[arg-type]


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def chip() -> FakeChip:
    return FakeChip()


@pytest.fixture
def radio(chip: FakeChip, clock: FakeClock) -> RFM69:
    radio = radio_on(chip, clock)
    radio.begin()
    return radio


def test_begin_leaves_exactly_the_documented_settings_in_the_chip(
    chip: FakeChip, radio: RFM69
) -> None:
    for address, value in DOCUMENTED_BS_REGISTERS.items():
        assert chip.registers[address] == value, f"register 0x{address:02X}"
    assert chip.mode == 0x10  # listening
    # The FIFO was cleared (RegIrqFlags2 <- 0x10) and no AES key was written.
    assert (0x28, 0x10) in chip.writes
    assert not any(0x3E <= address <= 0x4D for address, _ in chip.writes)


def test_begin_writes_in_a_fixed_order_after_checking_the_chip(
    chip: FakeChip, radio: RFM69
) -> None:
    assert chip.transactions[0] == [0x10, 0]  # RegVersion first
    # Then the two-way SPI check, then every register once, RegOpMode standby first.
    assert chip.writes[:3] == [(0x2F, 0xAA), (0x2F, 0x55), (0x01, 0x04)]
    config_writes = chip.writes[2 : 2 + len(radio.settings.registers())]
    assert config_writes == radio.settings.registers()
    assert {a for a, _ in config_writes} >= set(DOCUMENTED_BS_REGISTERS) - {0x25}


def test_the_robot_end_and_a_low_power_module_get_their_own_values(
    chip: FakeChip, clock: FakeClock
) -> None:
    radio_on(chip, clock, RadioSettings(node=2, network=7, high_power=False)).begin()
    assert chip.registers[0x39] == 0x02
    assert chip.registers[0x30] == 0x07
    assert chip.registers[0x11] == 0x9F


def test_an_aes_key_goes_into_the_key_registers_in_one_burst(
    chip: FakeChip, clock: FakeClock
) -> None:
    radio_on(chip, clock, RadioSettings(aes_key=KEY)).begin()
    assert [0x3E | 0x80, *KEY] in chip.transactions
    assert [chip.registers[0x3E + k] for k in range(16)] == list(KEY)
    assert chip.registers[0x3D] == 0x13  # AesOn


@pytest.mark.parametrize("version", [0x00, 0xFF, 0x23])
def test_a_missing_radio_is_reported_clearly(clock: FakeClock, version: int) -> None:
    chip = FakeChip(version=version)
    with pytest.raises(RadioError, match=rf"no radio: RegVersion reads 0x{version:02X}"):
        radio_on(chip, clock).begin()
    assert chip.writes == []  # nothing is written to something that is not an RFM69


def test_a_one_way_spi_bus_is_reported(clock: FakeClock) -> None:
    with pytest.raises(RadioError, match="SPI write check failed"):
        radio_on(FakeChip(keeps_writes=False), clock).begin()


def test_an_spi_failure_is_a_radio_error(clock: FakeClock) -> None:
    with pytest.raises(RadioError, match="SPI transfer failed"):
        radio_on(FakeChip(fail_spi=True), clock).begin()


def test_a_mode_switch_that_never_completes_times_out_on_the_given_clock(
    chip: FakeChip, clock: FakeClock
) -> None:
    radio = radio_on(chip, clock, mode_ready_timeout_s=0.01)
    chip.mode_ready = False
    with pytest.raises(RadioError, match=r"timed out after 10 ms switching to standby mode"):
        radio.begin()
    assert 0.01 <= clock.now_s < 0.012  # waited on the fake clock, not the real one


def test_send_puts_the_frame_in_the_fifo_transmits_and_listens_again(
    chip: FakeChip, radio: RFM69
) -> None:
    frame = bytes([5, 2, 1, 0, 1, 1])
    chip.writes.clear()
    radio.send(frame)
    assert chip.sent == [frame]
    assert [0x80, *frame] in chip.transactions  # one FIFO burst, length byte first
    modes = [value & 0x1C for address, value in chip.writes if address == 0x01]
    assert modes == [0x04, 0x0C, 0x04, 0x10]  # standby, TX, standby, RX
    dio = [value for address, value in chip.writes if address == 0x25]
    assert dio == [0x00, 0x40]  # PacketSent on DIO0 for TX, PayloadReady after
    assert radio.frames_sent == 1


@pytest.mark.parametrize(
    ("frame", "words"),
    [
        (b"", "2 to 66"),
        (bytes([0]), "2 to 66"),
        (bytes([3, 1, 2]), "length byte"),
        (bytes([66]) + bytes(66), "2 to 66"),
    ],
)
def test_send_refuses_a_malformed_frame(
    chip: FakeChip, radio: RFM69, frame: bytes, words: str
) -> None:
    with pytest.raises(RadioError, match=words):
        radio.send(frame)
    assert chip.sent == []


def test_a_frame_that_is_never_sent_times_out_and_the_radio_listens_again(
    chip: FakeChip, clock: FakeClock, radio: RFM69
) -> None:
    chip.tx_completes = False
    start_s = clock.now_s
    with pytest.raises(RadioError, match="timed out after 30 ms sending a frame"):
        radio.send(bytes([1, 2]))
    assert 0.03 <= clock.now_s - start_s < 0.032
    assert chip.mode == 0x10


def test_receive_returns_the_frame_and_its_rssi_read_while_still_in_rx(
    chip: FakeChip, radio: RFM69
) -> None:
    frame = bytes([4, 1, 2, 0, 9])
    chip.inject(frame, rssi_dbm=-71.5)
    assert radio.receive(0.01) == (frame, -71.5)
    assert chip.rssi_read_in_mode == [0x10]
    assert chip.mode == 0x10  # listening for the next one
    assert radio.last_rssi_dbm == -71.5
    assert radio.frames_received == 1


def test_receive_gives_up_after_its_timeout(chip: FakeChip, clock: FakeClock, radio: RFM69) -> None:
    start_s = clock.now_s
    assert radio.receive(0.025) is None
    assert 0.025 <= clock.now_s - start_s < 0.026
    before = clock.now_s
    assert radio.receive(0.0) is None  # a look, no wait
    assert clock.now_s == before


@pytest.mark.parametrize("length", [0, 66, 200])
def test_an_impossible_length_byte_is_dropped(chip: FakeChip, radio: RFM69, length: int) -> None:
    chip.inject(bytes([length, 1, 2]))
    assert radio.receive(0.005) is None
    assert radio.bad_lengths == 1
    chip.inject(bytes([1, 7]))
    assert radio.receive(0.005) == (bytes([1, 7]), -60.0)


def test_a_dio0_line_replaces_polling_the_irq_flags(chip: FakeChip, clock: FakeClock) -> None:
    radio = radio_on(chip, clock, dio0=lambda: bool(chip.payload_ready or chip.packet_sent))
    radio.begin()
    chip.transactions.clear()
    assert radio.receive(0.001) is None
    assert [0x28, 0] not in chip.transactions


def test_the_rssi_is_minus_half_the_register(chip: FakeChip, radio: RFM69) -> None:
    chip.rssi_raw = 181
    assert radio.read_rssi_dbm() == -90.5


def test_configured_notices_a_chip_that_lost_its_settings(chip: FakeChip, radio: RFM69) -> None:
    assert radio.configured()
    chip.registers[0x07] = 0xE4  # a reset chip is back at 915 MHz
    assert not radio.configured()


def test_close_puts_the_radio_to_sleep(chip: FakeChip, radio: RFM69) -> None:
    radio.close()
    assert chip.mode == 0x00


def test_settings_are_checked() -> None:
    with pytest.raises(RadioError, match="aes_key must be 16 bytes"):
        RadioSettings(aes_key=b"short")
    with pytest.raises(RadioError, match="broadcast"):
        RadioSettings(node=255)
    with pytest.raises(RadioError, match="network must be a byte"):
        RadioSettings(network=256)
    assert "aes_key" not in repr(RadioSettings(aes_key=KEY))


def test_an_aes_key_is_parsed_from_32_hex_digits() -> None:
    assert parse_aes_key(KEY.hex().upper()) == KEY
    with pytest.raises(RadioError, match="32 hex digits"):
        parse_aes_key("abcd")
    with pytest.raises(RadioError, match="hex digits only"):
        parse_aes_key("zz" * 16)


@pytest.mark.skipif(os.path.exists("/dev/spidev0.0"), reason="a real SPI device is present")
def test_opening_a_missing_spi_device_says_how_to_fix_it() -> None:
    with pytest.raises(RadioError, match=r"spidev"):
        open_spidev(0, 0)
