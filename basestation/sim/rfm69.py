"""An RFM69 (Semtech SX1231) emulated at the SPI register level.

The base station's driver talks to :class:`EmulatedRFM69` exactly as it talks to the module
through ``spidev``: ``xfer2([address | 0x80, value, ...])`` writes, ``xfer2([address, 0, ...])``
reads. What the emulation covers (SX1231 datasheet, section 6 register map):

- every register at its datasheet **reset** value (the "Reset" column, not Semtech's
  recommended "Default": a driver must write what it needs), RegVersion 0x24;
- SPI semantics: bit 7 of the first byte selects a write; the address auto-increments over a
  burst, except RegFifo (0x00) whose bursts push or pop the FIFO. The answer has the length of
  the request: ``0x00`` for the address byte, then the register values read or, on a write,
  the values the registers held **before** the write (what the chip shifts out on MISO;
  ``0x00`` for FIFO bytes);
- RegOpMode modes sleep, standby, FS, TX and RX with ModeReady after the datasheet's typical
  start-up times (:class:`ModeTimings`); listen mode and the automatic modes are not emulated;
- RegIrqFlags1/2: ModeReady, RxReady, TxReady, PllLock, Rssi, SyncAddressMatch, FifoFull,
  FifoNotEmpty, FifoLevel, FifoOverrun (write 1: clears the FIFO), PacketSent, PayloadReady,
  CrcOk;
- the 66-byte FIFO, packet mode, fixed or variable length (length byte first), CRC on/off
  with CrcAutoClearOff, node/broadcast address filtering, PayloadLength as the RX limit,
  RestartRx, AutoRxRestartOn with InterPacketRxDelay;
- AES: both ends must hold the same key with AesOn, otherwise the receiver drops the packet
  (the real chip would deliver garbage that fails the protocol decoder); AES padding counts
  in the airtime;
- TX: entering TX mode with the start condition met (RegFifoThresh bit 7: FIFO not empty, or
  FifoLevel) transmits one packet per entry into TX; PacketSent rises one airtime later
  (docs/protocol.md §5). The packet is taken from the FIFO at the end of the SPI transfer
  that meets the start condition, so write the whole frame in one burst, or before entering
  TX; a frame shorter than its length byte is an underrun and goes out corrupted. Leaving TX
  before PacketSent truncates the packet on air;
- RX: a packet is received when the chip was in RX and ready before its first bit, stayed
  in RX to its last, and is not holding an unread packet; RegRssiValue = -2 * RSSI (dBm).

Time comes from an injected clock. Nothing runs in the background: pending events (mode
ready, packet sent, packets arriving) are evaluated when the chip is accessed, so the chip is
exact under a fake clock and correct under ``time.monotonic``.

One thing: one emulated chip, register by register; its size is the datasheet's register map,
modes and timings, which split across files would have to be read together anyway.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Protocol

from basestation.radio.registers import (
    ADDRESS_FILTERING_NODE_OR_BROADCAST,
    AES_KEY_BYTES,
    FIFO_SIZE,
    FIFOTHRESH_LEVEL_MASK,
    FIFOTHRESH_TX_START_NOT_EMPTY,
    IRQ1_MODE_READY,
    IRQ1_PLL_LOCK,
    IRQ1_RSSI,
    IRQ1_RX_READY,
    IRQ1_SYNC_ADDRESS_MATCH,
    IRQ1_TX_READY,
    IRQ2_CRC_OK,
    IRQ2_FIFO_FULL,
    IRQ2_FIFO_LEVEL,
    IRQ2_FIFO_NOT_EMPTY,
    IRQ2_FIFO_OVERRUN,
    IRQ2_PACKET_SENT,
    IRQ2_PAYLOAD_READY,
    MODE_FS,
    MODE_NAMES,
    MODE_RX,
    MODE_SLEEP,
    MODE_STANDBY,
    MODE_TX,
    OPMODE_UNUSED_MASK,
    OSC1_RCCAL_DONE,
    OSC1_RCCAL_START,
    PACKET1_ADDRESS_FILTERING_MASK,
    PACKET1_ADDRESS_FILTERING_SHIFT,
    PACKET1_CRC_AUTO_CLEAR_OFF,
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
    REG_AFCLSB,
    REG_AFCMSB,
    REG_BITRATELSB,
    REG_BITRATEMSB,
    REG_BROADCASTADRS,
    REG_DIOMAPPING1,
    REG_FEILSB,
    REG_FEIMSB,
    REG_FIFO,
    REG_FIFOTHRESH,
    REG_FRFLSB,
    REG_FRFMID,
    REG_FRFMSB,
    REG_IRQFLAGS1,
    REG_IRQFLAGS2,
    REG_NODEADRS,
    REG_OPMODE,
    REG_OSC1,
    REG_PACKETCONFIG1,
    REG_PACKETCONFIG2,
    REG_PALEVEL,
    REG_PAYLOADLENGTH,
    REG_PREAMBLELSB,
    REG_PREAMBLEMSB,
    REG_RSSICONFIG,
    REG_RSSITHRESH,
    REG_RSSIVALUE,
    REG_SYNCCONFIG,
    REG_SYNCVALUE1,
    REG_TEMP1,
    REG_TEMP2,
    REG_TESTPA1,
    REG_TESTPA2,
    REG_VERSION,
    RESET_VALUES,
    RSSICONFIG_DONE,
    RSSICONFIG_START,
    SPI_ADDRESS_MASK,
    SPI_WRITE,
    SYNCCONFIG_SIZE_MASK,
    SYNCCONFIG_SIZE_SHIFT,
    SYNCCONFIG_SYNC_ON,
    TESTPA1_BOOST,
    TESTPA2_BOOST,
    dio0_mapping,
    opmode_mode,
    opmode_with_mode,
)
from basestation.sim.channel import (
    FXOSC_HZ,
    AirFrame,
    AirPort,
    AirSignature,
    Channel,
    Reception,
    TxHandle,
    aes_key_id,
    airtime_s,
)
from basestation.sim.clock import Clock

#: Registers (or bits) the chip alone writes; SPI writes to them are ignored.
_READ_ONLY: Final = frozenset(
    {REG_VERSION, REG_RSSIVALUE, REG_AFCMSB, REG_AFCLSB, REG_FEIMSB, REG_FEILSB, REG_TEMP2}
)


class SpiDevice(Protocol):
    """The subset of ``spidev.SpiDev`` the base station's driver uses."""

    def xfer2(self, data: list[int]) -> list[int]: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class ModeTimings:
    """Start-up times from the SX1231 datasheet (typical values, section 4 and 2.x timing
    table): crystal start from sleep, synthesizer lock, PA ramp, receiver start."""

    oscillator_s: float = 250e-6  # TS_OSC: sleep -> standby
    synthesizer_s: float = 60e-6  # TS_FS: standby -> FS
    transmitter_s: float = 55e-6  # TS_TR: FS -> TX (5 us + 1.25 PaRamp at the 40 us reset value)
    receiver_s: float = 150e-6  # TS_RE at 125 kHz bandwidth: FS -> RX ready
    to_standby_s: float = 10e-6  # TX/RX/FS -> standby: the oscillator is already running

    def transition_s(self, old: int, new: int) -> float:
        if new == old:
            return 0.0
        if new == MODE_SLEEP:
            return 0.0
        delay = self.oscillator_s if old == MODE_SLEEP else 0.0
        if new == MODE_STANDBY:
            return delay if old == MODE_SLEEP else self.to_standby_s
        if old not in (MODE_FS, MODE_TX, MODE_RX):
            delay += self.synthesizer_s
        if new == MODE_TX:
            delay += self.transmitter_s
        elif new == MODE_RX:
            delay += self.receiver_s
        return delay


INSTANT: Final = ModeTimings(0.0, 0.0, 0.0, 0.0, 0.0)


class EmulatedRFM69:
    """One RFM69 module on the simulated air.

    ``channel`` connects it to other radios (optional: without one, transmissions go nowhere).
    ``clock`` defaults to the channel's clock, else ``time.monotonic``.
    """

    def __init__(
        self,
        *,
        channel: Channel | None = None,
        clock: Clock | None = None,
        timings: ModeTimings | None = None,
        noise_floor_dbm: float = -112.0,
        sensitivity_dbm: float = -105.0,
        seed: int = 0,
        name: str = "rfm69",
    ) -> None:
        if clock is None:
            clock = channel.clock if channel is not None else None
        if clock is None:
            clock = time.monotonic
        self._clock: Clock = clock
        self._timings = timings if timings is not None else ModeTimings()
        self._noise_floor_dbm = noise_floor_dbm
        self._sensitivity_dbm = sensitivity_dbm
        self._rng = random.Random(seed)
        self.name = name
        self._lock = threading.RLock()
        self._incoming: list[Reception] = []
        self._channel = channel
        self._port: AirPort | None = None
        self._closed = False
        self.frames_sent = 0
        self.frames_received = 0
        self.frames_dropped = 0
        self._power_on(self._clock())
        if channel is not None:
            self._port = channel.attach(self)

    # --- power and reset ----------------------------------------------------------------------

    def _power_on(self, now_s: float) -> None:
        self._regs = bytearray(SPI_ADDRESS_MASK + 1)
        for address, value in RESET_VALUES.items():
            self._regs[address] = value
        self._fifo = bytearray()
        self._mode = MODE_STANDBY
        self._mode_ready_at = now_s
        self._fifo_overrun = False
        self._packet_sent = False
        self._payload_ready = False
        self._crc_ok = False
        self._sync_match = False
        self._rssi_flag = False
        self._rssi_done = True
        # TX: "idle" until the start condition, "sending" until PacketSent, then "done" until
        # the chip leaves TX (one packet per entry into TX).
        self._tx_state = "idle"
        self._tx_end_s = 0.0
        self._tx_handle: TxHandle | None = None
        # RX: the time from which a packet's first bit can be caught (None: not listening).
        self._listen_from: float | None = None
        self._busy_until = float("-inf")

    def reset(self) -> None:
        """A pulse on the RESET pin: every register back to its reset value, FIFO empty."""
        with self._lock:
            now_s = self._clock()
            self._update(now_s)
            self._abort_tx(now_s)
            self._incoming.clear()
            self._power_on(now_s)

    def close(self) -> None:
        """Like ``spidev.SpiDev.close``: the device can no longer be used."""
        self._closed = True

    # --- SPI ----------------------------------------------------------------------------------

    def xfer2(self, data: Sequence[int]) -> list[int]:
        """One SPI transaction with chip select held low for all of ``data``."""
        if self._closed:
            raise OSError("the SPI device is closed")
        values = list(data)
        for value in values:
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFF:
                raise ValueError(f"SPI bytes are integers in 0..255, got {value!r}")
        if not values:
            return []
        with self._lock:
            now_s = self._clock()
            self._update(now_s)
            address = values[0] & SPI_ADDRESS_MASK
            write = bool(values[0] & SPI_WRITE)
            answer = [0x00]
            for value in values[1:]:
                if write:
                    answer.append(self._write(address, value, now_s))
                else:
                    answer.append(self._read(address, now_s))
                if address != REG_FIFO:
                    address = (address + 1) & SPI_ADDRESS_MASK
            self._maybe_start_tx(now_s)
            return answer

    @property
    def dio0(self) -> bool:
        """The DIO0 pin, packet-mode mapping (RegDioMapping1 bits 7-6).

        RX: 00 CrcOk, 01 PayloadReady, 10 SyncAddress, 11 Rssi. TX: 00 PacketSent,
        01 TxReady, 11 PllLock. Low in every other mode and mapping.
        """
        with self._lock:
            now_s = self._clock()
            self._update(now_s)
            mapping = dio0_mapping(self._regs[REG_DIOMAPPING1])
            flags1 = self._irq_flags1(now_s)
            if self._mode == MODE_RX:
                return bool(
                    (self._crc_ok, self._payload_ready, self._sync_match, self._rssi_flag)[mapping]
                )
            if self._mode == MODE_TX:
                return bool(
                    (
                        self._packet_sent,
                        flags1 & IRQ1_TX_READY,
                        False,
                        flags1 & IRQ1_PLL_LOCK,
                    )[mapping]
                )
            return False

    # --- inspection (tests; never used by a driver) -------------------------------------------

    def peek(self, address: int) -> int:
        """A register's value as a read would return it, without side effects on the FIFO."""
        with self._lock:
            now_s = self._clock()
            self._update(now_s)
            if address == REG_FIFO:
                return self._fifo[0] if self._fifo else 0
            return self._read(address, now_s)

    @property
    def mode(self) -> str:
        return MODE_NAMES[self._mode]

    @property
    def fifo(self) -> bytes:
        with self._lock:
            self._update(self._clock())
            return bytes(self._fifo)

    # --- the channel's side -------------------------------------------------------------------

    def receive_air(self, reception: Reception) -> None:
        with self._lock:
            self._incoming.append(reception)

    # --- registers ----------------------------------------------------------------------------

    def _irq_flags1(self, now_s: float) -> int:
        ready = now_s >= self._mode_ready_at
        flags = 0
        if ready:
            flags |= IRQ1_MODE_READY
            if self._mode == MODE_RX:
                flags |= IRQ1_RX_READY
            if self._mode == MODE_TX:
                flags |= IRQ1_TX_READY
            if self._mode in (MODE_FS, MODE_TX, MODE_RX):
                flags |= IRQ1_PLL_LOCK
        if self._rssi_flag:
            flags |= IRQ1_RSSI
        if self._sync_match:
            flags |= IRQ1_SYNC_ADDRESS_MATCH
        return flags

    def _irq_flags2(self) -> int:
        count = len(self._fifo)
        flags = 0
        if count >= FIFO_SIZE:
            flags |= IRQ2_FIFO_FULL
        if count:
            flags |= IRQ2_FIFO_NOT_EMPTY
        if count > (self._regs[REG_FIFOTHRESH] & FIFOTHRESH_LEVEL_MASK):
            flags |= IRQ2_FIFO_LEVEL
        if self._fifo_overrun:
            flags |= IRQ2_FIFO_OVERRUN
        if self._packet_sent:
            flags |= IRQ2_PACKET_SENT
        if self._payload_ready:
            flags |= IRQ2_PAYLOAD_READY
        if self._crc_ok:
            flags |= IRQ2_CRC_OK
        return flags

    def _read(self, address: int, now_s: float) -> int:
        if address == REG_FIFO:
            if not self._fifo:
                return 0x00
            value = self._fifo.pop(0)
            if not self._fifo:
                self._fifo_emptied(now_s)
            return value
        if address == REG_IRQFLAGS1:
            return self._irq_flags1(now_s)
        if address == REG_IRQFLAGS2:
            return self._irq_flags2()
        if address == REG_RSSICONFIG:
            return RSSICONFIG_DONE if self._rssi_done else 0x00
        return self._regs[address]

    def _write(self, address: int, value: int, now_s: float) -> int:
        if address == REG_FIFO:
            if len(self._fifo) >= FIFO_SIZE:
                self._fifo_overrun = True  # the byte is lost
            else:
                self._fifo.append(value)
            return 0x00
        old = self._read(address, now_s)
        if address in _READ_ONLY:
            return old
        if address == REG_OPMODE:
            mode = opmode_mode(value)
            if mode in MODE_NAMES:
                self._regs[address] = value & ~OPMODE_UNUSED_MASK & 0xFF
                self._set_mode(mode, now_s)
            else:  # a reserved mode: keep the running one
                self._regs[address] = opmode_with_mode(value & ~OPMODE_UNUSED_MASK, self._mode)
        elif address == REG_IRQFLAGS1:
            # Rssi and SyncAddressMatch clear on writing 1; the rest is the chip's.
            if value & IRQ1_RSSI:
                self._rssi_flag = False
            if value & IRQ1_SYNC_ADDRESS_MATCH:
                self._sync_match = False
        elif address == REG_IRQFLAGS2:
            if value & IRQ2_FIFO_OVERRUN:  # docs/protocol.md: "write 0x10: clears the FIFO"
                self._fifo_overrun = False
                self._clear_fifo(now_s)
        elif address == REG_RSSICONFIG:
            if value & RSSICONFIG_START and self._mode == MODE_RX:
                self._regs[REG_RSSIVALUE] = self._rssi_register(self._rssi_now(now_s))
                self._rssi_done = True
        elif address == REG_PACKETCONFIG2:
            self._regs[address] = value & ~PACKET2_RESTART_RX & 0xFF
            if value & PACKET2_RESTART_RX:
                self._restart_rx(now_s)
        elif address == REG_OSC1:
            # RcCalStart: the calibration is done at once.
            self._regs[address] = (value & ~OSC1_RCCAL_START & 0xFF) | OSC1_RCCAL_DONE
        elif address == REG_TEMP1:
            # TempMeasStart finishes at once: not running, as after reset.
            self._regs[address] = RESET_VALUES[REG_TEMP1]
        else:
            self._regs[address] = value
        return old

    # --- modes --------------------------------------------------------------------------------

    def _set_mode(self, mode: int, now_s: float) -> None:
        old = self._mode
        if mode == old:
            return
        if old == MODE_TX:
            self._abort_tx(now_s)
            self._packet_sent = False  # "cleared when exiting Tx"
            self._tx_state = "idle"
        if old == MODE_RX:
            self._listen_from = None
            self._sync_match = False
            self._rssi_flag = False
        self._mode = mode
        self._mode_ready_at = now_s + self._timings.transition_s(old, mode)
        if mode == MODE_RX:
            # A packet still unread in the FIFO blocks reception until the FIFO is emptied
            # or RX is restarted (the robot's driver restarts RX for exactly this reason).
            self._listen_from = None if self._payload_ready else self._mode_ready_at
        if mode == MODE_TX:
            self._tx_state = "idle"

    def _restart_rx(self, now_s: float) -> None:
        self._clear_fifo(now_s)
        self._payload_ready = False
        self._crc_ok = False
        self._sync_match = False
        if self._mode == MODE_RX:
            self._listen_from = max(now_s, self._mode_ready_at)

    def _clear_fifo(self, now_s: float) -> None:
        had_packet = self._payload_ready
        self._fifo.clear()
        self._fifo_emptied(now_s, had_packet=had_packet)

    def _fifo_emptied(self, now_s: float, *, had_packet: bool | None = None) -> None:
        if had_packet is None:
            had_packet = self._payload_ready
        self._payload_ready = False  # "cleared when FIFO is empty"
        self._crc_ok = False
        if had_packet:
            self._sync_match = False
            if self._mode == MODE_RX and self._regs[REG_PACKETCONFIG2] & PACKET2_AUTO_RX_RESTART:
                delay_bits = 2 ** (
                    self._regs[REG_PACKETCONFIG2] >> PACKET2_INTER_PACKET_RX_DELAY_SHIFT
                )
                self._listen_from = max(now_s, self._mode_ready_at) + delay_bits / self._bitrate()

    # --- air settings from the registers ------------------------------------------------------

    def _bitrate_raw(self) -> int:
        return max(1, (self._regs[REG_BITRATEMSB] << 8) | self._regs[REG_BITRATELSB])

    def _bitrate(self) -> float:
        return FXOSC_HZ / self._bitrate_raw()

    def _aes_on(self) -> bool:
        return bool(self._regs[REG_PACKETCONFIG2] & PACKET2_AES_ON)

    def _variable_length(self) -> bool:
        return bool(self._regs[REG_PACKETCONFIG1] & PACKET1_VARIABLE_LENGTH)

    def _crc_on(self) -> bool:
        return bool(self._regs[REG_PACKETCONFIG1] & PACKET1_CRC_ON)

    def _address_filtering(self) -> int:
        return (
            self._regs[REG_PACKETCONFIG1] & PACKET1_ADDRESS_FILTERING_MASK
        ) >> PACKET1_ADDRESS_FILTERING_SHIFT

    def _sync_bytes(self) -> bytes:
        config = self._regs[REG_SYNCCONFIG]
        if not config & SYNCCONFIG_SYNC_ON:
            return b""
        size = ((config & SYNCCONFIG_SIZE_MASK) >> SYNCCONFIG_SIZE_SHIFT) + 1
        return bytes(self._regs[REG_SYNCVALUE1 : REG_SYNCVALUE1 + size])

    def signature(self) -> AirSignature:
        frf = (
            (self._regs[REG_FRFMSB] << 16) | (self._regs[REG_FRFMID] << 8) | self._regs[REG_FRFLSB]
        )
        key = (
            bytes(self._regs[REG_AESKEY1 : REG_AESKEY1 + AES_KEY_BYTES]) if self._aes_on() else None
        )
        return AirSignature(
            frf=frf,
            bitrate_raw=self._bitrate_raw(),
            sync=self._sync_bytes(),
            crc_on=self._crc_on(),
            variable_length=self._variable_length(),
            aes_key_id=aes_key_id(key),
        )

    def tx_power_dbm(self) -> float:
        """Output power from RegPaLevel (and the +20 dBm test registers of the RFM69HW)."""
        pa = self._regs[REG_PALEVEL]
        level = pa & PALEVEL_OUTPUT_POWER_MASK
        if pa & PALEVEL_PA1_ON and pa & PALEVEL_PA2_ON:  # PA1 + PA2 on PA_BOOST
            boost = (
                self._regs[REG_TESTPA1] == TESTPA1_BOOST
                and self._regs[REG_TESTPA2] == TESTPA2_BOOST
            )
            return -11.0 + level if boost else -14.0 + level
        if pa & (PALEVEL_PA0_ON | PALEVEL_PA1_ON | PALEVEL_PA2_ON):  # PA0 alone or PA1 alone
            return -18.0 + level
        return -60.0  # no amplifier enabled: practically nothing leaves the antenna

    def packet_airtime_s(self, frame_len: int) -> float:
        preamble = (self._regs[REG_PREAMBLEMSB] << 8) | self._regs[REG_PREAMBLELSB]
        plaintext = (1 if self._variable_length() else 0) + (1 if self._address_filtering() else 0)
        return airtime_s(
            frame_len,
            bitrate_bps=self._bitrate(),
            preamble_bytes=preamble,
            sync_bytes=len(self._sync_bytes()),
            crc=self._crc_on(),
            aes=self._aes_on(),
            plaintext_bytes=plaintext,
        )

    @staticmethod
    def _rssi_register(rssi_dbm: float) -> int:
        return max(0, min(0xFF, round(-2.0 * rssi_dbm)))

    def _rssi_now(self, now_s: float) -> float:
        for reception in self._incoming:
            if reception.start_s <= now_s < reception.end_s and self._hears(reception):
                return reception.rssi_dbm
        return self._noise_floor_dbm + self._rng.uniform(-1.0, 1.0)

    def _hears(self, reception: Reception) -> bool:
        return (
            reception.frame.signature.heard_by(self.signature())
            and reception.rssi_dbm >= self._sensitivity_dbm
        )

    # --- transmission -------------------------------------------------------------------------

    def _tx_start_condition(self) -> bool:
        if self._regs[REG_FIFOTHRESH] & FIFOTHRESH_TX_START_NOT_EMPTY:
            return bool(self._fifo)
        return len(self._fifo) > (self._regs[REG_FIFOTHRESH] & FIFOTHRESH_LEVEL_MASK)

    def _maybe_start_tx(self, now_s: float) -> None:
        if self._mode != MODE_TX or self._tx_state != "idle" or not self._tx_start_condition():
            return
        start_s = max(now_s, self._mode_ready_at)
        variable = self._variable_length()
        wanted = self._fifo[0] + 1 if variable else self._regs[REG_PAYLOADLENGTH]
        data = bytes(self._fifo[:wanted])
        del self._fifo[:wanted]
        underrun = len(data) < wanted
        signature = self.signature()
        duration_s = self.packet_airtime_s(wanted)
        self._tx_state = "sending"
        self._tx_end_s = start_s + duration_s
        self.frames_sent += 1
        if self._port is None or self._channel is None:
            self._tx_handle = None
            return
        frame = AirFrame(
            tx_id=self._channel_tx_id(),
            data=data,
            start_s=start_s,
            airtime_s=duration_s,
            signature=signature,
            tx_power_dbm=self.tx_power_dbm(),
            corrupted=underrun,
        )
        self._tx_handle = self._port.transmit(frame)

    def _channel_tx_id(self) -> int:
        next_id = getattr(self._channel, "next_tx_id", None)
        return int(next_id()) if next_id is not None else 0

    def _abort_tx(self, now_s: float) -> None:
        if self._tx_state == "sending" and now_s < self._tx_end_s:
            if self._tx_handle is not None and self._port is not None:
                self._port.abort(self._tx_handle, now_s)
            self._tx_state = "idle"
        self._tx_handle = None

    # --- lazy evaluation ----------------------------------------------------------------------

    def _update(self, now_s: float) -> None:
        if self._port is not None:
            self._port.sync(now_s)  # the robot answers before we look at the air
        if self._tx_state == "sending" and now_s >= self._tx_end_s:
            self._tx_state = "done"
            self._packet_sent = True
            self._tx_handle = None
        if not self._incoming:
            return
        due = [r for r in self._incoming if r.end_s <= now_s]
        if not due:
            return
        self._incoming = [r for r in self._incoming if r.end_s > now_s]
        for reception in sorted(due, key=lambda r: r.start_s):
            self._receive(reception)

    def _receive(self, reception: Reception) -> None:
        if reception.never_sent or not self._hears(reception):
            return
        listen_from = self._listen_from
        if (
            self._mode != MODE_RX
            or listen_from is None
            or listen_from > reception.start_s
            or self._busy_until > reception.start_s  # locked on an earlier packet
        ):
            self.frames_dropped += 1
            return
        self._busy_until = reception.end_s
        self._regs[REG_RSSIVALUE] = self._rssi_register(reception.rssi_dbm)
        threshold_dbm = -self._regs[REG_RSSITHRESH] / 2.0
        self._rssi_flag = reception.rssi_dbm >= threshold_dbm
        # A packet the chip rejects restarts reception once it is over.
        restart_at = reception.end_s
        mine = self.signature()
        theirs = reception.frame.signature
        data = reception.frame.data
        if theirs.aes_key_id != mine.aes_key_id:
            self.frames_dropped += 1
            self._listen_from = restart_at
            return
        crc_failed = (
            reception.corrupted
            or reception.truncated
            or theirs.crc_on != mine.crc_on
            or theirs.variable_length != mine.variable_length
        )
        if mine.variable_length:
            if not data or data[0] != len(data) - 1:
                crc_failed = True
            if not data or data[0] > self._regs[REG_PAYLOADLENGTH] or len(data) > FIFO_SIZE:
                self.frames_dropped += 1
                self._listen_from = restart_at
                return
        elif len(data) != self._regs[REG_PAYLOADLENGTH]:
            crc_failed = True
        filtering = self._address_filtering()
        if filtering:
            offset = 1 if mine.variable_length else 0
            destination = data[offset] if len(data) > offset else -1
            accepted = {self._regs[REG_NODEADRS]}
            if filtering == ADDRESS_FILTERING_NODE_OR_BROADCAST:
                accepted.add(self._regs[REG_BROADCASTADRS])
            if destination not in accepted:
                self.frames_dropped += 1
                self._listen_from = restart_at
                return
        self._sync_match = True
        if (
            crc_failed
            and mine.crc_on
            and not self._regs[REG_PACKETCONFIG1] & PACKET1_CRC_AUTO_CLEAR_OFF
        ):
            # CrcAutoClearOff = 0: the FIFO is cleared and the packet never shows up.
            self.frames_dropped += 1
            self._sync_match = False
            self._listen_from = restart_at
            return
        if crc_failed and not mine.crc_on and data:
            # Without CRC nothing catches the damage: a byte arrives flipped.
            damaged = bytearray(data)
            damaged[self._rng.randrange(len(damaged))] ^= 1 << self._rng.randrange(8)
            data = bytes(damaged)
        self._fifo = bytearray(data)
        self._payload_ready = True
        self._crc_ok = mine.crc_on and not crc_failed
        self._listen_from = None  # until the FIFO is read out or RX restarted
        self.frames_received += 1
