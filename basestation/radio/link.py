"""The robot behind the radio: one command frame out, one telemetry frame back per tick.

:class:`RadioRobotLink` is the agent's :class:`~basestation.robot.Robot` over an RFM69
(real, or the simulator's emulated chip): it numbers and encodes each command
(docs/protocol.md §2.1), sends it, waits a bounded time for the telemetry frame that
echoes it (§2.2, §4), decodes it, places the GPS position on the rail, and keeps the link
statistics the agent's ``/status`` reports. No answer is a :class:`RobotLinkError`, exactly
like the simulated robot's: the manager then stores no sample (nothing is invented) and the
robot's own dead-man stops it if the silence lasts.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, Literal, Protocol

from basestation.protocol import (
    BASESTATION_NODE,
    DEAD_MAN_MS,
    IDENTITY_CONFIG_FIELDS,
    PROTOCOL_VERSION,
    ROBOT_NODE,
    TELEMETRY_FRAME_SIZE,
    VELOCITY_LIMIT_MM_S,
    CommandFlag,
    CommandFrame,
    ConfigAckFrame,
    ConfigFrame,
    Direction,
    FixQuality,
    Frame,
    FrameError,
    IdentifyFrame,
    IdentityFrame,
    TelemetryFrame,
    TelemetryStatus,
    decode_frame,
    encode_command,
    encode_config,
    encode_identify,
)
from basestation.radio.rfm69 import RadioError
from basestation.robot import Command, RobotIdentity, RobotLimits, RobotLinkError, Telemetry
from basestation.telemetry.gps import DEFAULT_STALE_AFTER_S, GpsTracker
from basestation.telemetry.rail import Rail

logger = logging.getLogger(__name__)

# A command/telemetry pair is 8.5 ms on air (9.5 ms with AES, docs/protocol.md §5) plus the
# robot's turnaround; 25 ms leaves half of a 20 Hz tick for the rest of the agent.
DEFAULT_REPLY_TIMEOUT_S: Final = 0.025
# 100 commands = 5 s at 20 Hz: long enough to smooth, short enough to show a fade.
DEFAULT_LOSS_WINDOW: Final = 100
# The robot's dead-man stops it after 0.5 s without a command: after 1 s of silence the
# robot is no longer under our control, the link is down (the agent's LINK_DOWN_AFTER_S).
DEFAULT_LINK_DOWN_AFTER_S: Final = 1.0
# The FIFO holds one frame; a few reads empty it even if frames keep arriving.
_MAX_STALE_DRAIN: Final = 4
SEQ_MODULO: Final = 0x10000

LinkState = Literal["up", "down"]


class FrameRadio(Protocol):
    """What the link needs of a radio (:class:`~basestation.radio.rfm69.RFM69`)."""

    def send(self, frame: bytes) -> None: ...

    def receive(
        self, timeout_s: float, *, earliest_s: float | None = None
    ) -> tuple[bytes, float] | None: ...

    def airtime_s(self, frame_len: int) -> float: ...


@dataclass(frozen=True)
class RadioTelemetry(Telemetry):
    """Telemetry as the radio delivers it: the agent's fields plus what the frame carries.

    ``track_m`` is the projection of a current GPS fix; while the position is unknown (no
    fix for longer than the stale time) it repeats the last known one (0.0 before any) and
    ``position_known`` is False — the agent's ``track_m`` cannot be empty yet.
    """

    seq: int  # the robot's telemetry counter
    echo_seq: int  # the last command the robot accepted for motion
    command_seq: int  # the command this frame answers
    command_accepted: bool  # echo_seq == command_seq
    robot_clock_ms: int
    lat_deg: float
    lon_deg: float
    fix_quality: FixQuality
    satellites: int
    status: TelemetryStatus
    position_known: bool
    lateral_m: float | None  # off the rail, positive outside; None without a position
    grid_id: str | None  # thesis position id (``A2``); None without a position
    rssi_dbm: float  # RSSI of this frame at the base station
    robot_rssi_dbm: int  # RSSI of the command at the robot

    @property
    def estop_latched(self) -> bool:
        return bool(self.status & TelemetryStatus.E_STOP_LATCHED)


@dataclass(frozen=True)
class LinkStats:
    state: LinkState
    frames_sent: int
    replies_received: int  # telemetry frames that answered a command (echo or not)
    replies_missing: int  # commands with no telemetry frame within the reply timeout
    echo_mismatches: int  # answers whose echo_seq was not the command just sent
    telemetry_gaps: int  # telemetry seq numbers never seen
    bad_frames: int  # frames that failed to decode or were not for us
    send_errors: int  # the radio failed to transmit
    loss_pct: float | None  # commands not confirmed, over the last ``window`` commands
    window: int  # commands in the loss window now
    rssi_dbm: float | None  # base station's RSSI of the last reply
    robot_rssi_dbm: int | None  # robot's RSSI of the command that reply answered
    age_s: float | None  # agent time since the last reply, None before any
    estop_release_pending: bool


class RadioRobotLink:
    """The agent's ``Robot`` over an RFM69. Call :meth:`exchange` from one thread only
    (the control loop); :meth:`stats` may be read from others."""

    def __init__(
        self,
        radio: FrameRadio,
        *,
        rail: Rail | None = None,
        reply_timeout_s: float = DEFAULT_REPLY_TIMEOUT_S,
        ttl_ms: int = DEAD_MAN_MS,
        loss_window: int = DEFAULT_LOSS_WINDOW,
        link_down_after_s: float = DEFAULT_LINK_DOWN_AFTER_S,
        gps_stale_after_s: float = DEFAULT_STALE_AFTER_S,
        node: int = BASESTATION_NODE,
        robot_node: int = ROBOT_NODE,
        clock: Callable[[], float] | None = None,
        first_seq: int = 1,
    ) -> None:
        if not 0 < reply_timeout_s <= 1.0:
            raise ValueError(f"reply_timeout_s must be in (0, 1], got {reply_timeout_s!r}")
        if not 0 <= ttl_ms <= 0xFFFF:
            raise ValueError(f"ttl_ms must be 0..65535, got {ttl_ms!r}")
        if loss_window < 1:
            raise ValueError(f"loss_window must be at least 1, got {loss_window!r}")
        self.radio = radio
        self.rail = rail if rail is not None else Rail.default()
        self.reply_timeout_s = reply_timeout_s
        self.ttl_ms = ttl_ms
        self.link_down_after_s = link_down_after_s
        self.node = node
        self.robot_node = robot_node
        # Reply waits run on the radio's clock (the simulator's, in tests and benchmarks).
        radio_clock = getattr(radio, "clock", None)
        self.clock: Callable[[], float] = (
            clock if clock is not None else radio_clock if callable(radio_clock) else time.monotonic
        )
        self.gps = GpsTracker(stale_after_s=gps_stale_after_s)
        self._next_seq = first_seq % SEQ_MODULO
        # The control thread appends, HTTP threads read /status: the window is shared.
        self._window_lock = threading.Lock()
        self._confirmed: deque[bool] = deque(maxlen=loss_window)
        self._last_telemetry_seq: int | None = None
        self._last_track_m = 0.0
        self._estop_sent = False
        self._release_pending = False
        self._frames_sent = 0
        self._replies_received = 0
        self._replies_missing = 0
        self._echo_mismatches = 0
        self._telemetry_gaps = 0
        self._bad_frames = 0
        self._send_errors = 0
        self._last_reply_at_s: float | None = None
        self._last_rssi_dbm: float | None = None
        self._last_robot_rssi_dbm: int | None = None
        self.last_telemetry: RadioTelemetry | None = None

    # -- the Robot protocol -----------------------------------------------------------------------

    def exchange(self, command: Command, now_s: float) -> RadioTelemetry:
        frame = self._command_frame(command)
        self._drain_stale()
        try:
            self.radio.send(encode_command(frame))
        except RadioError as exc:
            self._send_errors += 1
            self._record_confirmed(False)
            raise RobotLinkError(f"command {frame.seq} not sent: {exc}") from exc
        self._frames_sent += 1

        # The robot answers once it has our frame: its telemetry is whole no sooner than its
        # own airtime after ours was sent.
        answer = self._await_telemetry(
            frame.seq, earliest_s=self.clock() + self.radio.airtime_s(TELEMETRY_FRAME_SIZE)
        )
        if answer is None:
            self._replies_missing += 1
            self._record_confirmed(False)
            raise RobotLinkError(
                f"no telemetry for command {frame.seq} within {self.reply_timeout_s * 1000:.0f} ms"
            )
        telemetry_frame, rssi_dbm = answer
        accepted = telemetry_frame.echo_seq == frame.seq
        if not accepted:
            # The robot answered but did not take this command (a lost or rejected
            # command, or a late answer to an earlier one): its measurements are real, the
            # command counts as lost.
            self._echo_mismatches += 1
        self._record_confirmed(accepted)
        telemetry = self._telemetry(telemetry_frame, frame.seq, accepted, rssi_dbm, now_s)
        if self._release_pending and accepted and not telemetry.estop_latched:
            self._release_pending = False
        return telemetry

    # -- extra operations -------------------------------------------------------------------------

    def release_estop(self) -> None:
        """Send ``E_STOP_RELEASE`` with the next commands until the robot reports the latch
        open (for a latch the agent did not set itself: the robot's local stop, or one kept
        in its EEPROM across a restart). A released robot moves only on a later command."""
        self._release_pending = True

    def configure(
        self, *, max_velocity_mps: float, accel_mps2: float, reply_timeout_s: float | None = None
    ) -> RobotLimits:
        """Send these limits in a config frame; return what the robot confirmed.

        The agent calls it once, at start-up, with its own ``AGENT_MAX_*`` limits (a run's
        lower limits need no config frame: the agent never commands faster than the run
        allows). The robot applies them within its compiled-in hard limits and answers with
        a config acknowledgement that carries its hard maximum too; a robot whose firmware
        predates the acknowledgement answers with a config frame (no hard maximum). Raises
        :class:`RobotLinkError` without an answer within ``reply_timeout_s`` (by default the
        control tick's).
        """
        frame = ConfigFrame(
            seq=self._take_seq(),
            max_velocity_mm_s=_mm(max_velocity_mps, VELOCITY_LIMIT_MM_S),
            accel_mm_s2=max(1, _mm(accel_mps2, 10_000)),
            to_node=self.robot_node,
            from_node=self.node,
        )
        self._drain_stale()
        try:
            self.radio.send(encode_config(frame))
        except RadioError as exc:
            self._send_errors += 1
            raise RobotLinkError(f"config {frame.seq} not sent: {exc}") from exc
        self._frames_sent += 1
        timeout_s = self.reply_timeout_s if reply_timeout_s is None else reply_timeout_s
        deadline_s = self.clock() + timeout_s
        while (remaining_s := deadline_s - self.clock()) > 0:
            decoded = self._receive_for_us(remaining_s)
            if decoded is None:
                continue
            reply, _ = decoded
            if isinstance(reply, ConfigAckFrame) and reply.seq == frame.seq:
                return RobotLimits(
                    max_velocity_mps=reply.max_velocity_mm_s / 1000.0,
                    max_accel_mps2=reply.accel_mm_s2 / 1000.0,
                    hard_max_velocity_mps=reply.hard_max_velocity_mm_s / 1000.0,
                )
            if isinstance(reply, ConfigFrame) and reply.seq == frame.seq:
                return RobotLimits(
                    max_velocity_mps=reply.max_velocity_mm_s / 1000.0,
                    max_accel_mps2=reply.accel_mm_s2 / 1000.0,
                    hard_max_velocity_mps=None,
                )
        raise RobotLinkError(f"no answer to config {frame.seq}")

    def identify(self, *, reply_timeout_s: float | None = None) -> RobotIdentity:
        """Ask the robot which firmware it runs (an identify frame) and return its answer:
        the build identifier and the compiled-in configuration. The agent asks once, at
        start-up, and records it with every run. Raises :class:`RobotLinkError` without an
        answer (a robot whose firmware predates the identity frame rejects the request)."""
        frame = IdentifyFrame(seq=self._take_seq(), to_node=self.robot_node, from_node=self.node)
        self._drain_stale()
        try:
            self.radio.send(encode_identify(frame))
        except RadioError as exc:
            self._send_errors += 1
            raise RobotLinkError(f"identify {frame.seq} not sent: {exc}") from exc
        self._frames_sent += 1
        timeout_s = self.reply_timeout_s if reply_timeout_s is None else reply_timeout_s
        deadline_s = self.clock() + timeout_s
        while (remaining_s := deadline_s - self.clock()) > 0:
            decoded = self._receive_for_us(remaining_s)
            if decoded is None:
                continue
            reply = decoded[0]
            if isinstance(reply, IdentityFrame) and reply.seq == frame.seq:
                return RobotIdentity(
                    build_id=reply.build_id,
                    config={name: int(getattr(reply, name)) for name in IDENTITY_CONFIG_FIELDS},
                    protocol_version=PROTOCOL_VERSION,
                )
        raise RobotLinkError(f"no answer to identify {frame.seq}")

    def stats(self, now_s: float) -> LinkStats:
        age_s = None if self._last_reply_at_s is None else max(0.0, now_s - self._last_reply_at_s)
        with self._window_lock:
            window = list(self._confirmed)
        return LinkStats(
            state="up" if age_s is not None and age_s <= self.link_down_after_s else "down",
            frames_sent=self._frames_sent,
            replies_received=self._replies_received,
            replies_missing=self._replies_missing,
            echo_mismatches=self._echo_mismatches,
            telemetry_gaps=self._telemetry_gaps,
            bad_frames=self._bad_frames,
            send_errors=self._send_errors,
            loss_pct=(100.0 * window.count(False) / len(window)) if window else None,
            window=len(window),
            rssi_dbm=self._last_rssi_dbm,
            robot_rssi_dbm=self._last_robot_rssi_dbm,
            age_s=age_s,
            estop_release_pending=self._release_pending,
        )

    # -- inside -----------------------------------------------------------------------------------

    def _record_confirmed(self, confirmed: bool) -> None:
        with self._window_lock:
            self._confirmed.append(confirmed)

    def _take_seq(self) -> int:
        seq = self._next_seq
        self._next_seq = (seq + 1) % SEQ_MODULO
        return seq

    def _command_frame(self, command: Command) -> CommandFrame:
        flags = CommandFlag(0)
        if command.estop:
            flags |= CommandFlag.E_STOP
            self._release_pending = False
        else:
            # The agent stopped asking for the e-stop: it has been released there, so release
            # the robot's latch too. A Command that says so itself is also honoured.
            if self._estop_sent or getattr(command, "estop_release", False):
                self._release_pending = True
            if self._release_pending:
                flags |= CommandFlag.E_STOP_RELEASE
        self._estop_sent = command.estop
        velocity_mps = command.velocity_mps
        if not math.isfinite(velocity_mps):
            logger.error("command velocity %r is not a number: sending 0", velocity_mps)
            velocity_mps = 0.0
        return CommandFrame(
            seq=self._take_seq(),
            velocity_mm_s=0 if command.estop else _mm(velocity_mps, VELOCITY_LIMIT_MM_S),
            direction=Direction.CW if command.direction == "cw" else Direction.CCW,
            flags=flags,
            ttl_ms=self.ttl_ms,
            to_node=self.robot_node,
            from_node=self.node,
        )

    def _drain_stale(self) -> None:
        # A frame still in the FIFO answers an earlier command: it must not be taken for
        # the answer to the next one.
        for _ in range(_MAX_STALE_DRAIN):
            if self.radio.receive(0.0) is None:
                return
            logger.debug("dropped a late frame")

    def _receive_for_us(
        self, timeout_s: float, earliest_s: float | None = None
    ) -> tuple[Frame, float] | None:
        try:
            received = self.radio.receive(timeout_s, earliest_s=earliest_s)
        except RadioError as exc:
            logger.warning("radio error while waiting for the robot: %s", exc)
            return None
        if received is None:
            return None
        raw, rssi_dbm = received
        try:
            frame = decode_frame(raw)
        except FrameError as exc:
            self._bad_frames += 1
            logger.debug("undecodable frame %s: %s", raw.hex(), exc)
            return None
        if frame.to_node != self.node or frame.from_node != self.robot_node:
            self._bad_frames += 1
            return None
        return frame, rssi_dbm

    def _await_telemetry(
        self, seq: int, earliest_s: float | None = None
    ) -> tuple[TelemetryFrame, float] | None:
        deadline_s = self.clock() + self.reply_timeout_s
        other: tuple[TelemetryFrame, float] | None = None
        while (remaining_s := deadline_s - self.clock()) > 0:
            decoded = self._receive_for_us(remaining_s, earliest_s)
            if decoded is None or not isinstance(decoded[0], TelemetryFrame):
                continue
            telemetry_frame, rssi_dbm = decoded[0], decoded[1]
            self._count_gap(telemetry_frame.seq)
            if telemetry_frame.echo_seq == seq:
                return telemetry_frame, rssi_dbm
            other = (telemetry_frame, rssi_dbm)  # keep waiting: the real answer may follow
        return other

    def _count_gap(self, seq: int) -> None:
        last = self._last_telemetry_seq
        self._last_telemetry_seq = seq
        if last is None:
            return
        missing = (seq - last - 1) % SEQ_MODULO
        # A jump backwards or far ahead is a robot restart, not thousands of lost frames.
        if 0 < missing < 1000:
            self._telemetry_gaps += missing

    def _telemetry(
        self,
        frame: TelemetryFrame,
        command_seq: int,
        accepted: bool,
        rssi_dbm: float,
        now_s: float,
    ) -> RadioTelemetry:
        self._replies_received += 1
        self._last_reply_at_s = now_s
        self._last_rssi_dbm = rssi_dbm
        self._last_robot_rssi_dbm = frame.rssi_dbm
        fix = self.gps.update(
            lat_deg=frame.lat_deg,
            lon_deg=frame.lon_deg,
            quality=frame.fix_quality,
            satellites=frame.satellites,
            now_s=now_s,
        )
        lateral_m: float | None = None
        grid: str | None = None
        if fix is not None:
            position = self.rail.project(fix.lat_deg, fix.lon_deg)
            self._last_track_m = position.track_m
            lateral_m = position.lateral_m
            grid = position.grid_id
        telemetry = RadioTelemetry(
            velocity_mps=frame.velocity_mps,
            direction="cw" if frame.direction == Direction.CW else "ccw",
            battery_v=frame.battery_v,
            track_m=self._last_track_m,
            seq=frame.seq,
            echo_seq=frame.echo_seq,
            command_seq=command_seq,
            command_accepted=accepted,
            robot_clock_ms=frame.robot_clock_ms,
            lat_deg=frame.lat_deg,
            lon_deg=frame.lon_deg,
            fix_quality=frame.fix_quality,
            satellites=frame.satellites,
            status=frame.status,
            position_known=fix is not None,
            lateral_m=lateral_m,
            grid_id=grid,
            rssi_dbm=rssi_dbm,
            robot_rssi_dbm=frame.rssi_dbm,
        )
        self.last_telemetry = telemetry
        return telemetry


def _mm(value: float, limit: int) -> int:
    """Metres to millimetres on the wire, clamped to what the frame can say."""
    if not math.isfinite(value):
        return 0
    return min(max(round(value * 1000.0), 0), limit)
