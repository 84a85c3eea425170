"""Register-level driver for the HopeRF RFM69 (Semtech SX1231) in packet mode.

Written from the datasheet's register map for the settings of docs/protocol.md §1, the
same values as the robot's ``firmware/robot/rfm69.cpp``. The only hardware interface is an
SPI device object with spidev's ``xfer2(list[int]) -> list[int]``: on the Pi a
``spidev.SpiDev`` (bus 0, device 0, mode 0, 4 MHz), in tests and the simulator the
emulated chip. IRQ flags are polled over SPI, so no GPIO is needed; a DIO0 reader can be
passed to avoid SPI traffic while waiting. No poll is made while a packet cannot yet have
crossed the air (its airtime at the configured bit rate): a send sleeps through its own
frame's airtime, a receive given ``earliest_s`` until then, so that a 50 Hz exchange costs a
few SPI reads instead of dozens.

SPI semantics: the first byte of a transaction is the register address, bit 7 set for a
write; further bytes go to (or come from) the following registers, except for RegFifo
(0x00) where every byte is the next FIFO byte.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Final, Protocol

from basestation.radio.airtime import airtime_s
from basestation.radio.registers import (
    ADDRESS_FILTERING_NODE_OR_BROADCAST,
    AES_KEY_BYTES,
    CHIP_VERSION,
    DIO0_RX_PAYLOAD_READY,
    DIO0_TX_PACKET_SENT,
    FIFO_SIZE,
    FIFOTHRESH_TX_START_NOT_EMPTY,
    IRQ1_MODE_READY,
    IRQ2_FIFO_OVERRUN,
    IRQ2_PACKET_SENT,
    IRQ2_PAYLOAD_READY,
    MODE_NAMES,
    MODE_RX,
    MODE_SLEEP,
    MODE_STANDBY,
    MODE_TX,
    PACKET1_ADDRESS_FILTERING_SHIFT,
    PACKET1_CRC_ON,
    PACKET1_VARIABLE_LENGTH,
    PACKET2_AES_ON,
    PACKET2_AUTO_RX_RESTART,
    PACKET2_INTER_PACKET_RX_DELAY_SHIFT,
    PACKET2_RESTART_RX,
    PALEVEL_OUTPUT_POWER_MASK,
    PALEVEL_PA0_ON,
    PALEVEL_PA1_ON,
    PALEVEL_PA2_ON,
    REG_AESKEY1,
    REG_BITRATELSB,
    REG_BITRATEMSB,
    REG_BROADCASTADRS,
    REG_DATAMODUL,
    REG_DIOMAPPING1,
    REG_DIOMAPPING2,
    REG_FDEVLSB,
    REG_FDEVMSB,
    REG_FIFO,
    REG_FIFOTHRESH,
    REG_FRFLSB,
    REG_FRFMID,
    REG_FRFMSB,
    REG_IRQFLAGS1,
    REG_IRQFLAGS2,
    REG_LNA,
    REG_NODEADRS,
    REG_OPMODE,
    REG_PACKETCONFIG1,
    REG_PACKETCONFIG2,
    REG_PALEVEL,
    REG_PAYLOADLENGTH,
    REG_PREAMBLELSB,
    REG_PREAMBLEMSB,
    REG_RSSITHRESH,
    REG_RSSIVALUE,
    REG_RXBW,
    REG_SYNCCONFIG,
    REG_SYNCVALUE1,
    REG_SYNCVALUE2,
    REG_TESTDAGC,
    REG_VERSION,
    SPI_ADDRESS_MASK,
    SPI_WRITE,
    SYNCCONFIG_SIZE_SHIFT,
    SYNCCONFIG_SYNC_ON,
    TESTDAGC_IMPROVED_LOW_BETA_OFF,
    dio_mapping1_with_dio0,
    opmode_with_mode,
)

# The settings of docs/protocol.md §1 that are not a plain number, in the map's terms.
SYNC_WORD_1: Final = 0x2D
SYNC_WORD_BYTES: Final = 2  # SYNC_WORD_1, then the network id
DEFAULT_NETWORK: Final = 100
PA_LEVEL_HIGH_POWER: Final = (  # RFM69HW/HCW: PA1 + PA2 on PA_BOOST, +17 dBm
    PALEVEL_PA1_ON | PALEVEL_PA2_ON | PALEVEL_OUTPUT_POWER_MASK
)
PA_LEVEL_LOW_POWER: Final = PALEVEL_PA0_ON | PALEVEL_OUTPUT_POWER_MASK  # RFM69W: PA0, +13 dBm
# Inter-packet RX delay 1 (2 bit times), auto RX restart on.
PACKET_CONFIG2: Final = (1 << PACKET2_INTER_PACKET_RX_DELAY_SHIFT) | PACKET2_AUTO_RX_RESTART
# DIO0 shows PayloadReady in RX and PacketSent in TX; DIO1-3 are unused (mapping 00).
RX_DIO_MAPPING: Final = dio_mapping1_with_dio0(0x00, DIO0_RX_PAYLOAD_READY)
TX_DIO_MAPPING: Final = dio_mapping1_with_dio0(0x00, DIO0_TX_PACKET_SENT)
MAX_FRAME_BYTES: Final = FIFO_SIZE  # length byte included
MAX_LENGTH_BYTE: Final = MAX_FRAME_BYTES - 1

# docs/protocol.md §1, in the order they are written. Node address, second sync byte, PA
# level and PacketConfig2 depend on the settings and follow these.
COMMON_REGISTERS: Final[tuple[tuple[int, int], ...]] = (
    (REG_OPMODE, opmode_with_mode(0x00, MODE_STANDBY)),  # sequencer on, listen off
    (REG_DATAMODUL, 0x00),  # packet mode, FSK, no shaping
    (REG_BITRATEMSB, 0x02),  # 32 MHz / 0x0240 = 55 555 bit/s
    (REG_BITRATELSB, 0x40),
    (REG_FDEVMSB, 0x03),  # 0x0333 x 61.035 Hz = 49.99 kHz
    (REG_FDEVLSB, 0x33),
    (REG_FRFMSB, 0x6C),  # 0x6C4000 x 61.035 Hz = 433.000 MHz
    (REG_FRFMID, 0x40),
    (REG_FRFLSB, 0x00),
    (REG_LNA, 0x88),  # 200 ohm input, gain by AGC
    (REG_RXBW, 0x42),  # DccFreq 010, mantissa 16, exponent 2: 125 kHz
    (REG_DIOMAPPING1, RX_DIO_MAPPING),
    (REG_DIOMAPPING2, 0x07),  # ClkOut off
    (REG_IRQFLAGS2, IRQ2_FIFO_OVERRUN),  # clears the FIFO
    (REG_RSSITHRESH, 0xDC),  # -110 dBm
    (REG_PREAMBLEMSB, 0x00),
    (REG_PREAMBLELSB, 0x03),  # 3-byte preamble
    # Sync on, 2 bytes, no bit errors tolerated.
    (REG_SYNCCONFIG, SYNCCONFIG_SYNC_ON | (SYNC_WORD_BYTES - 1) << SYNCCONFIG_SIZE_SHIFT),
    (REG_SYNCVALUE1, SYNC_WORD_1),
    (  # variable length, CRC on, auto clear, node or broadcast
        REG_PACKETCONFIG1,
        PACKET1_VARIABLE_LENGTH
        | PACKET1_CRC_ON
        | ADDRESS_FILTERING_NODE_OR_BROADCAST << PACKET1_ADDRESS_FILTERING_SHIFT,
    ),
    (REG_PAYLOADLENGTH, FIFO_SIZE),  # longest frame accepted in RX
    (REG_BROADCASTADRS, 0xFF),
    # TX starts as soon as the FIFO is not empty (the level, 15, is the reset value).
    (REG_FIFOTHRESH, FIFOTHRESH_TX_START_NOT_EMPTY | 0x0F),
    (REG_TESTDAGC, TESTDAGC_IMPROVED_LOW_BETA_OFF),  # continuous DAGC, improved fading margin
)
# Registers that hold what was written (RegOpMode and RegIrqFlags2 change by themselves,
# the AES key is write-only): read back after initialisation to prove the chip took them.
_NOT_VERIFIED: Final = frozenset({REG_OPMODE, REG_IRQFLAGS2, REG_DIOMAPPING1})

# Waits. ModeReady comes within tens of microseconds (standby) to about a millisecond (RX
# from sleep); a 66-byte frame is 10.5 ms on air at 55.555 kbps, AES adds about 0.5 ms.
DEFAULT_MODE_READY_TIMEOUT_S: Final = 0.010
DEFAULT_PACKET_SENT_TIMEOUT_S: Final = 0.030
DEFAULT_POLL_INTERVAL_S: Final = 0.0002
# Mode switches take 10 to 250 us: a finer poll keeps six of them per exchange from costing
# a millisecond of waiting.
DEFAULT_MODE_POLL_INTERVAL_S: Final = 0.00002
# A wait through a packet's airtime ends this much early: the first look must not come late.
AIRTIME_WAKE_EARLY_S: Final = 0.0005


class SpiDevice(Protocol):
    """The part of ``spidev.SpiDev`` the driver uses: one full-duplex transaction."""

    def xfer2(self, data: list[int]) -> list[int]: ...


class RadioError(Exception):
    """The radio is absent, misconfigured, or did not do what it was told in time."""


@dataclass(frozen=True)
class RadioSettings:
    node: int = 1  # RegNodeAdrs: BS 1, robot 2 (docs/protocol.md §1)
    network: int = DEFAULT_NETWORK  # the second sync byte
    high_power: bool = True  # RFM69HW/HCW; False for the RFM69W
    aes_key: bytes | None = field(default=None, repr=False)  # 16 bytes; both ends must agree

    def __post_init__(self) -> None:
        for name in ("node", "network"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFF:
                raise RadioError(f"{name} must be a byte (0..255), got {value!r}")
        if self.node == 0xFF:
            raise RadioError("node 255 is the broadcast address, not a node address")
        if self.aes_key is not None and (
            not isinstance(self.aes_key, bytes | bytearray) or len(self.aes_key) != AES_KEY_BYTES
        ):
            raise RadioError(f"aes_key must be {AES_KEY_BYTES} bytes (32 hex digits)")

    @property
    def pa_level(self) -> int:
        return PA_LEVEL_HIGH_POWER if self.high_power else PA_LEVEL_LOW_POWER

    @property
    def packet_config2(self) -> int:
        return PACKET_CONFIG2 | (PACKET2_AES_ON if self.aes_key is not None else 0)

    def registers(self) -> list[tuple[int, int]]:
        """Every (address, value) written at initialisation except the AES key, in order."""
        return [
            *COMMON_REGISTERS,
            (REG_SYNCVALUE2, self.network),
            (REG_NODEADRS, self.node),
            (REG_PALEVEL, self.pa_level),
            (REG_PACKETCONFIG2, self.packet_config2),
        ]


def parse_aes_key(text: str) -> bytes:
    """A 16-byte key from 32 hex digits (the firmware's ``AES_KEY`` format)."""
    cleaned = text.strip()
    if len(cleaned) != 2 * AES_KEY_BYTES:
        raise RadioError(f"an AES key is {2 * AES_KEY_BYTES} hex digits, got {len(cleaned)}")
    try:
        return bytes.fromhex(cleaned)
    except ValueError:
        raise RadioError("an AES key is hex digits only (0-9, a-f)") from None


class RFM69:
    """One RFM69 behind an SPI device.

    ``clock`` (monotonic seconds) and ``sleep`` are injectable so that a simulator's clock
    drives every wait. ``dio0``, if given, reads the DIO0 pin: PayloadReady in RX,
    PacketSent in TX. Call :meth:`begin` before anything else.
    """

    def __init__(
        self,
        spi: SpiDevice,
        settings: RadioSettings | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        dio0: Callable[[], bool] | None = None,
        mode_ready_timeout_s: float = DEFAULT_MODE_READY_TIMEOUT_S,
        packet_sent_timeout_s: float = DEFAULT_PACKET_SENT_TIMEOUT_S,
        poll_interval_s: float = DEFAULT_POLL_INTERVAL_S,
        mode_poll_interval_s: float = DEFAULT_MODE_POLL_INTERVAL_S,
    ) -> None:
        self.spi = spi
        self.settings = settings if settings is not None else RadioSettings()
        self.clock = clock
        self.sleep = sleep
        self.dio0 = dio0
        self.mode_ready_timeout_s = mode_ready_timeout_s
        self.packet_sent_timeout_s = packet_sent_timeout_s
        self.poll_interval_s = poll_interval_s
        self.mode_poll_interval_s = mode_poll_interval_s
        self.mode: int | None = None  # the RegOpMode mode field value last set (MODE_*)
        self.last_rssi_dbm: float | None = None
        self.frames_sent = 0
        self.frames_received = 0
        self.bad_lengths = 0  # FIFO contents with an impossible length byte, dropped

    # -- SPI ---------------------------------------------------------------------------------

    def _xfer(self, data: list[int]) -> list[int]:
        try:
            answer = self.spi.xfer2(data)
        except OSError as exc:
            raise RadioError(f"SPI transfer failed: {exc}") from exc
        if len(answer) != len(data):
            raise RadioError(f"SPI transfer returned {len(answer)} bytes for {len(data)}")
        return list(answer)

    def read_register(self, address: int) -> int:
        return self._xfer([address & SPI_ADDRESS_MASK, 0])[1]

    def write_register(self, address: int, value: int) -> None:
        self._xfer([address | SPI_WRITE, value & 0xFF])

    def read_burst(self, address: int, count: int) -> bytes:
        return bytes(self._xfer([address & SPI_ADDRESS_MASK] + [0] * count)[1:])

    def write_burst(self, address: int, values: Sequence[int]) -> None:
        self._xfer([address | SPI_WRITE, *values])

    # -- set-up ------------------------------------------------------------------------------

    def begin(self) -> None:
        """Check the chip, write every register of docs/protocol.md §1, verify, enter RX."""
        version = self.read_register(REG_VERSION)
        if version != CHIP_VERSION:
            raise RadioError(
                f"no radio: RegVersion reads 0x{version:02X}, an RFM69 reads "
                f"0x{CHIP_VERSION:02X} (check the wiring, the SPI bus and device, and that "
                "the module is powered and out of reset)"
            )
        # The SPI bus must work both ways: a register keeps what is written to it.
        for pattern in (0xAA, 0x55):
            self.write_register(REG_SYNCVALUE1, pattern)
            read_back = self.read_register(REG_SYNCVALUE1)
            if read_back != pattern:
                raise RadioError(
                    f"SPI write check failed: wrote 0x{pattern:02X} to RegSyncValue1, "
                    f"read 0x{read_back:02X} (MOSI or chip select not connected?)"
                )
        registers = self.settings.registers()
        for address, value in registers:
            self.write_register(address, value)
        if self.settings.aes_key is not None:
            # One burst: the address auto-increments over RegAesKey1..16.
            self.write_burst(REG_AESKEY1, list(self.settings.aes_key))
        self.set_mode(MODE_STANDBY)
        for address, value in registers:
            if address in _NOT_VERIFIED:
                continue
            read_back = self.read_register(address)
            if read_back != value:
                raise RadioError(
                    f"register 0x{address:02X} reads 0x{read_back:02X} after writing "
                    f"0x{value:02X}: the radio did not take its configuration"
                )
        self.start_receiving()

    def configured(self) -> bool:
        """The configuration is still in the chip (a brown-out resets the module alone)."""
        return all(
            self.read_register(address) == value
            for address, value in self.settings.registers()
            if address not in _NOT_VERIFIED
        )

    # -- modes -------------------------------------------------------------------------------

    def set_mode(self, mode: int) -> None:
        """Switch to ``mode`` (a mode field value, ``MODE_*``) and wait for ModeReady
        (bounded)."""
        opmode = self.read_register(REG_OPMODE)
        self.write_register(REG_OPMODE, opmode_with_mode(opmode, mode))
        self.mode = mode
        self._wait(
            lambda: bool(self.read_register(REG_IRQFLAGS1) & IRQ1_MODE_READY),
            self.mode_ready_timeout_s,
            f"switching to {MODE_NAMES.get(mode, hex(mode))} mode",
            self.mode_poll_interval_s,
        )

    def start_receiving(self) -> None:
        # A PayloadReady left over keeps the FIFO full and blocks reception: restart RX.
        if self.read_register(REG_IRQFLAGS2) & IRQ2_PAYLOAD_READY:
            packet_config2 = self.read_register(REG_PACKETCONFIG2)
            self.write_register(REG_PACKETCONFIG2, packet_config2 | PACKET2_RESTART_RX)
        self.write_register(REG_DIOMAPPING1, RX_DIO_MAPPING)
        self.set_mode(MODE_RX)

    def standby(self) -> None:
        self.set_mode(MODE_STANDBY)

    def sleep_mode(self) -> None:
        """The lowest-power mode (the agent is stopping)."""
        self.set_mode(MODE_SLEEP)

    def clear_fifo(self) -> None:
        self.write_register(REG_IRQFLAGS2, IRQ2_FIFO_OVERRUN)

    def airtime_s(self, frame_len: int) -> float:
        """Seconds on air of a frame of ``frame_len`` FIFO bytes with these settings."""
        return airtime_s(frame_len, aes=self.settings.aes_key is not None)

    def _quiet_until(self, at_s: float) -> None:
        """Sleep, without a poll, until shortly before ``at_s`` (on the radio's clock)."""
        wait_s = at_s - AIRTIME_WAKE_EARLY_S - self.clock()
        if wait_s > 0:
            self.sleep(wait_s)

    # -- frames ------------------------------------------------------------------------------

    def send(self, frame: bytes) -> None:
        """Transmit one frame (length byte first) and go back to RX.

        Raises :class:`RadioError` for a malformed frame or when PacketSent does not come
        within ``packet_sent_timeout_s`` (the radio is put back into RX either way).
        """
        if not 2 <= len(frame) <= MAX_FRAME_BYTES:
            raise RadioError(f"a frame is 2 to {MAX_FRAME_BYTES} bytes, got {len(frame)}")
        if frame[0] != len(frame) - 1:
            raise RadioError(
                f"length byte {frame[0]} does not match the {len(frame) - 1} bytes after it"
            )
        self.set_mode(MODE_STANDBY)
        self.clear_fifo()
        self.write_burst(REG_FIFO, list(frame))
        self.write_register(REG_DIOMAPPING1, TX_DIO_MAPPING)
        try:
            self.set_mode(MODE_TX)
            # PacketSent comes no sooner than the frame's airtime after TX began.
            self._quiet_until(self.clock() + self.airtime_s(len(frame)))
            self._wait(
                self._packet_sent,
                self.packet_sent_timeout_s,
                "sending a frame",
                self.poll_interval_s,
            )
        finally:
            self.set_mode(MODE_STANDBY)
            self.start_receiving()
        self.frames_sent += 1

    def receive(
        self, timeout_s: float, *, earliest_s: float | None = None
    ) -> tuple[bytes, float] | None:
        """Wait up to ``timeout_s`` for a frame; return it (length byte first) with its RSSI
        in dBm, or ``None``. ``timeout_s=0`` looks once without waiting. A FIFO holding an
        impossible length is dropped and the wait goes on. ``earliest_s`` (the radio's clock)
        is when the awaited frame can have arrived at the soonest: no look before then."""
        deadline_s = self.clock() + max(timeout_s, 0.0)
        if self.mode != MODE_RX:
            self.start_receiving()
        if earliest_s is not None:
            self._quiet_until(min(earliest_s, deadline_s))
        while True:
            if self._payload_ready():
                received = self._read_frame()
                if received is not None:
                    return received
            if self.clock() >= deadline_s:
                return None
            self.sleep(self.poll_interval_s)

    def read_rssi_dbm(self) -> float:
        """The RSSI the chip measures now (meaningful in RX): -RegRssiValue / 2 dBm."""
        return -self.read_register(REG_RSSIVALUE) / 2.0

    def close(self) -> None:
        """Put the radio to sleep and release the SPI device if it can be closed."""
        try:
            self.sleep_mode()
        finally:
            close = getattr(self.spi, "close", None)
            if callable(close):
                close()

    def _packet_sent(self) -> bool:
        if self.dio0 is not None:
            return self.dio0()
        return bool(self.read_register(REG_IRQFLAGS2) & IRQ2_PACKET_SENT)

    def _payload_ready(self) -> bool:
        if self.dio0 is not None and self.mode == MODE_RX:
            return self.dio0()
        return bool(self.read_register(REG_IRQFLAGS2) & IRQ2_PAYLOAD_READY)

    def _read_frame(self) -> tuple[bytes, float] | None:
        # RSSI belongs to this packet only while the chip is still in RX.
        rssi_dbm = self.read_rssi_dbm()
        self.set_mode(MODE_STANDBY)
        length = self.read_burst(REG_FIFO, 1)[0]
        if not 1 <= length <= MAX_LENGTH_BYTE:
            self.bad_lengths += 1
            self.clear_fifo()
            self.start_receiving()
            return None
        payload = self.read_burst(REG_FIFO, length)
        self.start_receiving()
        self.last_rssi_dbm = rssi_dbm
        self.frames_received += 1
        return bytes([length]) + payload, rssi_dbm

    def _wait(
        self, done: Callable[[], bool], timeout_s: float, what: str, poll_interval_s: float
    ) -> None:
        deadline_s = self.clock() + timeout_s
        while not done():
            if self.clock() >= deadline_s:
                # One last look: a slow poll may have slept past a flag that is now set.
                if done():
                    return
                raise RadioError(
                    f"timed out after {timeout_s * 1000:.0f} ms {what} "
                    f"(RegOpMode 0x{self.read_register(REG_OPMODE):02X}, "
                    f"RegIrqFlags1 0x{self.read_register(REG_IRQFLAGS1):02X}, "
                    f"RegIrqFlags2 0x{self.read_register(REG_IRQFLAGS2):02X})"
                )
            self.sleep(poll_interval_s)


def open_spidev(bus: int = 0, device: int = 0, *, speed_hz: int = 4_000_000) -> SpiDevice:
    """Open ``/dev/spidev<bus>.<device>`` for the RFM69 (mode 0, MSB first)."""
    try:
        import spidev  # the Pi only; an optional dependency elsewhere
    except ImportError:
        raise RadioError(
            "the spidev package is not installed (pip install 'amazing-mobile-node[basestation]')"
        ) from None
    spi = spidev.SpiDev()
    try:
        spi.open(bus, device)
    except OSError as exc:
        raise RadioError(
            f"cannot open /dev/spidev{bus}.{device}: {exc.strerror} (is SPI enabled? "
            "raspi-config → Interface Options → SPI)"
        ) from exc
    spi.max_speed_hz = speed_hz
    spi.mode = 0
    spi.bits_per_word = 8
    spi.lsbfirst = False
    device_handle: SpiDevice = spi
    return device_handle
