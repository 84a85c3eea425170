"""The air between simulated radios: loss, latency, RSSI and link cuts.

A transmitting radio hands the channel an :class:`AirFrame` (the packet as its FIFO held it,
its start time and airtime, and the settings a receiver must share to hear it). The channel
delivers a :class:`Reception` to every other radio: the same frame with a start time on the
receiver's clock, an RSSI, and whether the channel corrupted it (a receiver with CRC on drops
a corrupted frame, as the RFM69 does with CrcAutoClearOff = 0).

Two transports with the same interface:

- :class:`InProcessChannel`: every radio in one process on one (usually fake) clock;
  deterministic for a given seed. Radios attached with ``lazy=True`` (the simulated robot)
  are advanced to "now" whenever another radio looks at the air, so a driver polling an
  emulated chip sees the robot's answers exactly when physics says they arrive.
- :class:`UdpChannel`: one radio per process, frames as JSON datagrams on 127.0.0.1 only,
  so the robot can run as its own process and outlive the agent.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import math
import random
import socket
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Final, Protocol

from basestation.radio.airtime import AES_BLOCK as AES_BLOCK
from basestation.radio.airtime import DEFAULT_BITRATE_RAW as DEFAULT_BITRATE_RAW
from basestation.radio.airtime import FXOSC_HZ as FXOSC_HZ
from basestation.radio.airtime import airtime_s as airtime_s
from basestation.sim.clock import Clock

LOOPBACK: Final = "127.0.0.1"
FSTEP_HZ: Final = FXOSC_HZ / 2**19
#: docs/protocol.md §1: 433 MHz (the bit rate, 55 555 bit/s, is the driver's too).
DEFAULT_FRF: Final = 0x6C4000
#: Free-space-ish loss between the base station and the robot on the roof, chosen so that the
#: robot's +17 dBm arrives at about -58 dBm: a strong, comfortable link.
DEFAULT_PATH_LOSS_DB: Final = 75.0
#: Below this an RFM69 at 55.5 kbit/s with 125 kHz bandwidth does not decode (datasheet order).
SENSITIVITY_DBM: Final = -105.0


def aes_key_id(key: bytes | None) -> str | None:
    """A short fingerprint of an AES key: both ends must share the key to hear each other,
    and the key itself never goes on the (simulated) air or into a datagram."""
    if key is None:
        return None
    return hashlib.sha256(b"amazing-sim-aes:" + bytes(key)).hexdigest()[:16]


@dataclass(frozen=True, slots=True)
class AirSignature:
    """What a receiver must share with the sender to demodulate and decode its packets."""

    frf: int = DEFAULT_FRF
    bitrate_raw: int = DEFAULT_BITRATE_RAW
    sync: bytes = b"\x2d\x64"  # empty when the sync word is off
    crc_on: bool = True
    variable_length: bool = True
    aes_key_id: str | None = None

    def heard_by(self, other: AirSignature) -> bool:
        """Carrier, bit rate and sync word match: the receiver finds the packet at all."""
        return (
            self.frf == other.frf
            and self.bitrate_raw == other.bitrate_raw
            and self.sync == other.sync
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "frf": self.frf,
            "bitrate_raw": self.bitrate_raw,
            "sync": self.sync.hex(),
            "crc_on": self.crc_on,
            "variable_length": self.variable_length,
            "aes_key_id": self.aes_key_id,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> AirSignature:
        key_id = data["aes_key_id"]
        return cls(
            frf=_int_field(data, "frf", 0, 0xFFFFFF),
            bitrate_raw=_int_field(data, "bitrate_raw", 1, 0xFFFF),
            sync=bytes.fromhex(str(data["sync"]))[:8],
            crc_on=bool(data["crc_on"]),
            variable_length=bool(data["variable_length"]),
            aes_key_id=None if key_id is None else str(key_id)[:64],
        )


@dataclass(frozen=True, slots=True)
class AirFrame:
    """One packet as transmitted: ``data`` is the FIFO content (length byte first in
    variable-length mode); ``start_s`` is on the sender's clock."""

    tx_id: int
    data: bytes
    start_s: float
    airtime_s: float
    signature: AirSignature
    tx_power_dbm: float
    corrupted: bool = False  # the sender's FIFO ran dry mid-packet


class TxHandle:
    """Lets a sender abort a packet it is still transmitting (it left TX mode early):
    receivers then get it corrupted, or not at all if it never started."""

    __slots__ = ("abort_at_s", "tx_id")

    def __init__(self, tx_id: int) -> None:
        self.tx_id = tx_id
        self.abort_at_s: float | None = None  # on the receiver's clock


@dataclass(frozen=True, slots=True)
class Reception:
    """A packet as one receiver experiences it, times on the receiver's clock."""

    frame: AirFrame
    start_s: float
    end_s: float
    rssi_dbm: float
    corrupted: bool
    handle: TxHandle

    @property
    def truncated(self) -> bool:
        abort = self.handle.abort_at_s
        return abort is not None and abort < self.end_s

    @property
    def never_sent(self) -> bool:
        abort = self.handle.abort_at_s
        return abort is not None and abort <= self.start_s


class AirRadio(Protocol):
    """Anything attached to a channel: the emulated chip, the robot's frame-level radio."""

    def receive_air(self, reception: Reception) -> None: ...


class LazyRadio(AirRadio, Protocol):
    """A radio whose owner must be brought up to a time before the air is looked at."""

    def advance_to(self, time_s: float) -> None: ...


class AirPort(Protocol):
    """A radio's connection to the air."""

    def transmit(self, frame: AirFrame) -> TxHandle: ...

    def abort(self, handle: TxHandle, at_s: float) -> None: ...

    def sync(self, now_s: float) -> None:
        """Bring every lazy participant up to ``now_s`` (in-process); no-op across processes."""
        ...


class Channel(Protocol):
    clock: Clock

    def attach(self, radio: AirRadio, *, lazy: bool = False) -> AirPort: ...

    def cut(self) -> None: ...

    def restore(self) -> None: ...


@dataclass
class ChannelStats:
    sent: int = 0
    delivered: int = 0
    corrupted: int = 0
    cut_dropped: int = 0
    malformed: int = 0  # UDP datagrams that were not frames (never from our own endpoints)


@dataclass
class _Link:
    """Loss, latency and RSSI of the air; shared by both transports."""

    loss_probability: float = 0.0
    latency_s: float = 0.0
    path_loss_db: float = DEFAULT_PATH_LOSS_DB
    rssi_sigma_db: float = 2.0
    seed: int = 0
    rng: random.Random = field(init=False)

    def __post_init__(self) -> None:
        if not 0.0 <= self.loss_probability <= 1.0:
            raise ValueError(f"loss_probability {self.loss_probability} not in 0..1")
        if not (math.isfinite(self.latency_s) and self.latency_s >= 0.0):
            raise ValueError(f"latency_s {self.latency_s} must be a finite value >= 0")
        if not (math.isfinite(self.rssi_sigma_db) and self.rssi_sigma_db >= 0.0):
            raise ValueError(f"rssi_sigma_db {self.rssi_sigma_db} must be >= 0")
        self.rng = random.Random(self.seed)

    def rssi_dbm(self, tx_power_dbm: float) -> float:
        return tx_power_dbm - self.path_loss_db + self.rng.gauss(0.0, self.rssi_sigma_db)

    def lost(self) -> bool:
        return self.loss_probability > 0.0 and self.rng.random() < self.loss_probability


class _InProcessPort:
    def __init__(self, channel: InProcessChannel, radio: AirRadio) -> None:
        self._channel = channel
        self._radio = radio

    def transmit(self, frame: AirFrame) -> TxHandle:
        return self._channel._transmit(self._radio, frame)

    def abort(self, handle: TxHandle, at_s: float) -> None:
        # One clock for everyone in process: the sender's time is the receivers' time.
        handle.abort_at_s = at_s + self._channel.latency_s

    def sync(self, now_s: float) -> None:
        self._channel.advance(now_s, caller=self._radio)


class InProcessChannel:
    """The air between radios of one process, on one clock."""

    def __init__(
        self,
        *,
        clock: Clock | None = None,
        loss_probability: float = 0.0,
        latency_s: float = 0.0,
        path_loss_db: float = DEFAULT_PATH_LOSS_DB,
        rssi_sigma_db: float = 2.0,
        seed: int = 0,
    ) -> None:
        self.clock: Clock = clock if clock is not None else time.monotonic
        self._link = _Link(loss_probability, latency_s, path_loss_db, rssi_sigma_db, seed)
        self._radios: list[AirRadio] = []
        self._lazy: list[LazyRadio] = []
        self._cut = False
        self._advancing = False
        self._lock = threading.RLock()
        self._tx_ids = itertools.count(1)
        self.stats = ChannelStats()

    @property
    def latency_s(self) -> float:
        return self._link.latency_s

    @property
    def loss_probability(self) -> float:
        return self._link.loss_probability

    @loss_probability.setter
    def loss_probability(self, value: float) -> None:
        if not 0.0 <= value <= 1.0:
            raise ValueError(f"loss_probability {value} not in 0..1")
        self._link.loss_probability = value

    @property
    def is_cut(self) -> bool:
        return self._cut

    def cut(self) -> None:
        """Nothing sent from now on reaches anyone (the robot drove out of range)."""
        self._cut = True

    def restore(self) -> None:
        self._cut = False

    def next_tx_id(self) -> int:
        return next(self._tx_ids)

    def attach(self, radio: AirRadio, *, lazy: bool = False) -> AirPort:
        with self._lock:
            self._radios.append(radio)
            if lazy:
                advance = getattr(radio, "advance_to", None)
                if advance is None:
                    raise TypeError("a lazy radio needs advance_to(time_s)")
                self._lazy.append(radio)  # type: ignore[arg-type]
        return _InProcessPort(self, radio)

    def advance(self, now_s: float, *, caller: AirRadio | None = None) -> None:
        """Bring every lazy radio (the simulated robot) up to ``now_s``."""
        with self._lock:
            if self._advancing:  # a robot transmitting while it advances: nothing to redo
                return
            self._advancing = True
            try:
                for radio in self._lazy:
                    if radio is not caller:
                        radio.advance_to(now_s)
            finally:
                self._advancing = False

    def _transmit(self, sender: AirRadio, frame: AirFrame) -> TxHandle:
        handle = TxHandle(frame.tx_id)
        with self._lock:
            self.stats.sent += 1
            if self._cut:
                self.stats.cut_dropped += 1
                return handle
            start_s = frame.start_s + self._link.latency_s
            for radio in self._radios:
                if radio is sender:
                    continue
                corrupted = frame.corrupted or self._link.lost()
                self.stats.delivered += 1
                self.stats.corrupted += int(corrupted)
                radio.receive_air(
                    Reception(
                        frame=frame,
                        start_s=start_s,
                        end_s=start_s + frame.airtime_s,
                        rssi_dbm=self._link.rssi_dbm(frame.tx_power_dbm),
                        corrupted=corrupted,
                        handle=handle,
                    )
                )
        return handle


def _int_field(data: dict[str, Any], name: str, low: int, high: int) -> int:
    value = data[name]
    if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
        raise ValueError(f"{name} {value!r} not an integer in {low}..{high}")
    return value


def _float_field(data: dict[str, Any], name: str, low: float, high: float) -> float:
    value = data[name]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} {value!r} is not a number")
    number = float(value)
    if not (math.isfinite(number) and low <= number <= high):
        raise ValueError(f"{name} {value!r} not in {low}..{high}")
    return number


class _UdpPort:
    def __init__(self, channel: UdpChannel) -> None:
        self._channel = channel

    def transmit(self, frame: AirFrame) -> TxHandle:
        return self._channel._transmit(frame)

    def abort(self, handle: TxHandle, at_s: float) -> None:
        self._channel._abort(handle, at_s)

    def sync(self, now_s: float) -> None:
        return None  # the other end runs in real time in its own process


class UdpChannel:
    """One process's end of the air, carried as JSON datagrams over 127.0.0.1.

    The sender puts a frame in a datagram the moment it starts transmitting, with the delay
    until its first bit and its airtime; the receiver schedules it on its own clock from the
    datagram's arrival (plus ``latency_s``). Loss and RSSI are drawn at the receiving end,
    and :meth:`cut` drops traffic both ways at this end.
    """

    MAX_DATAGRAM = 4096
    #: Aborts refer to recent transmissions only.
    _RECENT = 64

    def __init__(
        self,
        *,
        local_port: int = 0,
        peer_port: int | None = None,
        clock: Clock | None = None,
        loss_probability: float = 0.0,
        latency_s: float = 0.0,
        path_loss_db: float = DEFAULT_PATH_LOSS_DB,
        rssi_sigma_db: float = 2.0,
        seed: int = 0,
    ) -> None:
        self.clock: Clock = clock if clock is not None else time.monotonic
        self._link = _Link(loss_probability, latency_s, path_loss_db, rssi_sigma_db, seed)
        self._lock = threading.Lock()
        self._radio: AirRadio | None = None
        self._peer_port = peer_port
        self._cut = False
        self._closed = False
        # Random start: a restarted peer must not mistake new ids for old ones.
        self._tx_ids = itertools.count(random.SystemRandom().randrange(1, 2**31))
        self._recent: OrderedDict[tuple[int, int], TxHandle] = OrderedDict()
        self.stats = ChannelStats()
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._socket.bind((LOOPBACK, local_port))
        except OSError:
            self._socket.close()
            raise
        self._socket.settimeout(0.2)
        self._thread = threading.Thread(
            target=self._receive_loop, name=f"sim-air-udp-{self.local_port}", daemon=True
        )
        self._thread.start()

    @property
    def local_port(self) -> int:
        return int(self._socket.getsockname()[1])

    @property
    def peer_port(self) -> int | None:
        return self._peer_port

    def connect(self, peer_port: int) -> None:
        if not 0 < peer_port < 65536:
            raise ValueError(f"peer_port {peer_port} not in 1..65535")
        self._peer_port = peer_port

    @property
    def latency_s(self) -> float:
        return self._link.latency_s

    @property
    def is_cut(self) -> bool:
        return self._cut

    def cut(self) -> None:
        self._cut = True

    def restore(self) -> None:
        self._cut = False

    def next_tx_id(self) -> int:
        return next(self._tx_ids) & 0x7FFFFFFF

    def attach(self, radio: AirRadio, *, lazy: bool = False) -> AirPort:
        # ``lazy`` is accepted for interface parity: a robot behind UDP runs in real time.
        with self._lock:
            if self._radio is not None:
                raise ValueError("a UDP channel end carries exactly one radio")
            self._radio = radio
        return _UdpPort(self)

    def close(self) -> None:
        self._closed = True
        self._thread.join(timeout=2.0)
        self._socket.close()

    def __enter__(self) -> UdpChannel:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- sending ------------------------------------------------------------------------------

    def _send(self, message: dict[str, Any]) -> None:
        if self._peer_port is None or self._closed:
            return
        payload = json.dumps(message, separators=(",", ":")).encode()
        # Nobody listening (the peer process is down): on the air that is just silence.
        with contextlib.suppress(OSError):
            self._socket.sendto(payload, (LOOPBACK, self._peer_port))

    def _transmit(self, frame: AirFrame) -> TxHandle:
        handle = TxHandle(frame.tx_id)
        self.stats.sent += 1
        if self._cut:
            self.stats.cut_dropped += 1
            return handle
        self._send(
            {
                "v": 1,
                "kind": "frame",
                "id": frame.tx_id,
                "data": frame.data.hex(),
                "delay_s": max(0.0, frame.start_s - self.clock()),
                "airtime_s": frame.airtime_s,
                "sig": frame.signature.to_json(),
                "power_dbm": frame.tx_power_dbm,
                "corrupted": frame.corrupted,
            }
        )
        return handle

    def _abort(self, handle: TxHandle, at_s: float) -> None:
        if self._cut:
            return
        self._send(
            {"v": 1, "kind": "abort", "id": handle.tx_id, "delay_s": max(0.0, at_s - self.clock())}
        )

    # --- receiving ----------------------------------------------------------------------------

    def _receive_loop(self) -> None:
        while not self._closed:
            try:
                payload, (host, port) = self._socket.recvfrom(self.MAX_DATAGRAM)
            except TimeoutError:
                continue
            except OSError:
                if self._closed:
                    return
                continue
            now_s = self.clock()
            if host != LOOPBACK or self._cut:
                if self._cut:
                    self.stats.cut_dropped += 1
                continue
            try:
                self._on_datagram(json.loads(payload), now_s, port)
            except (ValueError, KeyError, TypeError):
                self.stats.malformed += 1

    def _on_datagram(self, message: Any, now_s: float, port: int) -> None:
        if not isinstance(message, dict) or message.get("v") != 1:
            raise ValueError("not a version-1 air datagram")
        kind = message["kind"]
        tx_id = _int_field(message, "id", 0, 2**31)
        delay_s = _float_field(message, "delay_s", 0.0, 10.0)
        if kind == "abort":
            handle = self._recent.get((port, tx_id))
            if handle is not None:
                handle.abort_at_s = now_s + delay_s + self._link.latency_s
            return
        if kind != "frame":
            raise ValueError(f"unknown datagram kind {kind!r}")
        data = bytes.fromhex(str(message["data"]))
        if len(data) > 255:
            raise ValueError("frame longer than a packet can be")
        frame = AirFrame(
            tx_id=tx_id,
            data=data,
            start_s=now_s + delay_s,
            airtime_s=_float_field(message, "airtime_s", 0.0, 1.0),
            signature=AirSignature.from_json(message["sig"]),
            tx_power_dbm=_float_field(message, "power_dbm", -30.0, 30.0),
            corrupted=bool(message["corrupted"]),
        )
        handle = TxHandle(tx_id)
        self._recent[(port, tx_id)] = handle
        while len(self._recent) > self._RECENT:
            self._recent.popitem(last=False)
        radio = self._radio
        if radio is None:
            return
        corrupted = frame.corrupted or self._link.lost()
        start_s = frame.start_s + self._link.latency_s
        self.stats.delivered += 1
        self.stats.corrupted += int(corrupted)
        radio.receive_air(
            Reception(
                frame=frame,
                start_s=start_s,
                end_s=start_s + frame.airtime_s,
                rssi_dbm=self._link.rssi_dbm(frame.tx_power_dbm),
                corrupted=corrupted,
                handle=handle,
            )
        )
