"""A register-recording stand-in for an RFM69 on SPI, and a fake clock.

Just enough of the chip for the driver's own tests: registers that keep what is written,
the FIFO, ModeReady, PacketSent on entering TX, PayloadReady for a frame put "on air" with
:meth:`FakeChip.inject`. The simulator's emulated chip (``basestation.sim``) is the full
model; this one records every SPI write so a test can check the exact init sequence.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from basestation.protocol import (
    CommandFlag,
    CommandFrame,
    ConfigAckFrame,
    ConfigFrame,
    Direction,
    FixQuality,
    TelemetryFrame,
    TelemetryStatus,
    decode_frame,
    encode_config,
    encode_config_ack,
    encode_telemetry,
)
from basestation.telemetry import Rail

OPMODE = 0x01
VERSION = 0x10
RSSIVALUE = 0x24
IRQFLAGS1 = 0x27
IRQFLAGS2 = 0x28
PACKETCONFIG2 = 0x3D
MODE_MASK = 0x1C
MODE_TX = 0x0C
MODE_RX = 0x10


@dataclass
class FakeClock:
    now_s: float = 0.0
    sleeps: int = 0

    def __call__(self) -> float:
        return self.now_s

    def sleep(self, duration_s: float) -> None:
        self.sleeps += 1
        self.now_s += max(duration_s, 1e-6)


@dataclass
class FakeChip:
    version: int = 0x24
    mode_ready: bool = True
    tx_completes: bool = True
    keeps_writes: bool = True
    fail_spi: bool = False
    rssi_raw: int = 120  # -60 dBm
    registers: list[int] = field(default_factory=lambda: [0] * 0x80)
    writes: list[tuple[int, int]] = field(default_factory=list)
    transactions: list[list[int]] = field(default_factory=list)
    fifo: deque[int] = field(default_factory=deque)
    sent: list[bytes] = field(default_factory=list)
    inbox: deque[tuple[bytes, int]] = field(default_factory=deque)
    payload_ready: bool = False
    packet_sent: bool = False
    rssi_read_in_mode: list[int] = field(default_factory=list)
    on_transmit: Callable[[bytes], None] | None = None

    @property
    def mode(self) -> int:
        return self.registers[OPMODE] & MODE_MASK

    def inject(self, frame: bytes, rssi_dbm: float = -60.0) -> None:
        """A frame arrives over the air (delivered to the FIFO once the chip is in RX)."""
        self.inbox.append((frame, round(-2 * rssi_dbm)))

    def xfer2(self, data: list[int]) -> list[int]:
        if self.fail_spi:
            raise OSError(5, "Input/output error")
        self.transactions.append(list(data))
        address = data[0] & 0x7F
        if data[0] & 0x80:
            for k, value in enumerate(data[1:]):
                self._write(address if address == 0 else address + k, value)
            return [0] * len(data)
        return [0] + [
            self._read(address if address == 0 else address + k) for k in range(len(data) - 1)
        ]

    def _write(self, address: int, value: int) -> None:
        self.writes.append((address, value))
        if address == 0x00:
            self.fifo.append(value)
        elif address == IRQFLAGS2:
            if value & 0x10:  # FifoOverrun: clears the FIFO
                self.fifo.clear()
                self.payload_ready = False
        elif address == OPMODE:
            self.registers[OPMODE] = value
            self.packet_sent = False
            if self.mode == MODE_TX and self.fifo and self.tx_completes:
                frame = bytes(self.fifo)
                self.fifo.clear()
                self.sent.append(frame)
                self.packet_sent = True
                if self.on_transmit is not None:
                    self.on_transmit(frame)
        elif address == PACKETCONFIG2:
            self.registers[address] = value & ~0x04  # RestartRx always reads 0
            if value & 0x04:
                self.fifo.clear()
                self.payload_ready = False
        elif self.keeps_writes and address != VERSION:
            self.registers[address] = value

    def _read(self, address: int) -> int:
        if address == 0x00:
            value = self.fifo.popleft() if self.fifo else 0
            if not self.fifo:
                self.payload_ready = False
            return value
        if address == VERSION:
            return self.version
        if address == IRQFLAGS1:
            return 0x80 if self.mode_ready else 0x00
        if address == IRQFLAGS2:
            if self.mode == MODE_RX and not self.payload_ready and self.inbox:
                frame, self.rssi_raw = self.inbox.popleft()
                self.fifo.clear()
                self.fifo.extend(frame)
                self.payload_ready = True
            return (
                (0x40 if self.fifo else 0)
                | (0x08 if self.packet_sent else 0)
                | (0x04 if self.payload_ready else 0)
            )
        if address == RSSIVALUE:
            self.rssi_read_in_mode.append(self.mode)
            return self.rssi_raw
        return self.registers[address]


@dataclass
class ScriptedRobot:
    """Answers each command put on air through ``chip`` the way docs/protocol.md §4 says,
    with a robot that moves along ``rail`` at the commanded speed (one 50 ms step per
    command) and reports its GPS position. Knobs make it misbehave."""

    chip: FakeChip
    rail: Rail
    track_m: float = 0.0
    fix_quality: int = 4
    answers: bool = True
    echo_delta: int = 0  # answer with echo_seq = seq + echo_delta (0: the command's own)
    seq_step: int = 1  # telemetry seq increment (2 = every other frame "lost")
    latched: bool = False
    local_stop: bool = False
    # Answer a config frame with an acknowledgement carrying this hard maximum; None answers
    # with a config frame, as firmware before the acknowledgement does.
    hard_max_mm_s: int | None = None
    battery_10mv: int = 6000
    before_answer: list[bytes] = field(default_factory=list)  # junk put on air first
    commands: list[CommandFrame] = field(default_factory=list)
    seq: int = 0
    period_s: float = 0.05

    def __post_init__(self) -> None:
        self.chip.on_transmit = self

    def __call__(self, raw: bytes) -> None:
        frame = decode_frame(raw)
        if isinstance(frame, ConfigFrame):
            if self.hard_max_mm_s is not None:
                ack = ConfigAckFrame(
                    seq=frame.seq,
                    max_velocity_mm_s=min(frame.max_velocity_mm_s, self.hard_max_mm_s),
                    accel_mm_s2=min(frame.accel_mm_s2, 2000),
                    hard_max_velocity_mm_s=self.hard_max_mm_s,
                    to_node=frame.from_node,
                    from_node=frame.to_node,
                )
                self.chip.inject(encode_config_ack(ack))
                return
            applied = ConfigFrame(
                seq=frame.seq,
                max_velocity_mm_s=min(frame.max_velocity_mm_s, 3000),
                accel_mm_s2=min(frame.accel_mm_s2, 2000),
                to_node=frame.from_node,
                from_node=frame.to_node,
            )
            self.chip.inject(encode_config(applied))
            return
        assert isinstance(frame, CommandFrame)
        self.commands.append(frame)
        if frame.flags & CommandFlag.E_STOP:
            self.latched = True
        elif frame.flags & CommandFlag.E_STOP_RELEASE and not self.local_stop:
            self.latched = False
        moving = not self.latched and not frame.flags & CommandFlag.E_STOP_RELEASE
        velocity_mm_s = frame.velocity_mm_s if moving else 0
        sign = 1 if frame.direction == Direction.CW else -1
        self.track_m = (self.track_m + sign * velocity_mm_s / 1000 * self.period_s) % (
            self.rail.length_m
        )
        if not self.answers:
            return
        for junk in self.before_answer:
            self.chip.inject(junk)
        self.seq = (self.seq + self.seq_step) % 0x10000
        lat, lon = self.rail.point_at(self.track_m)
        status = TelemetryStatus(0)
        if self.latched:
            status |= TelemetryStatus.E_STOP_LATCHED
        if self.local_stop:
            status |= TelemetryStatus.LOCAL_STOP
        telemetry = TelemetryFrame(
            seq=self.seq,
            echo_seq=(frame.seq + self.echo_delta) % 0x10000,
            robot_clock_ms=len(self.commands) * 50,
            velocity_mm_s=velocity_mm_s,
            direction=frame.direction,
            battery_10mv=self.battery_10mv,
            lat_e7=round(lat * 1e7),
            lon_e7=round(lon * 1e7),
            fix_quality=FixQuality(self.fix_quality),
            satellites=14 if self.fix_quality else 0,
            status=status,
            rssi_dbm=-48,
            to_node=frame.from_node,
            from_node=frame.to_node,
        )
        self.chip.inject(encode_telemetry(telemetry), rssi_dbm=-55.0)
