"""The simulated robot: the firmware core (through ctypes) driving the rail physics.

:class:`SimulatedRobot` does what ``firmware/robot/robot.ino`` does, with the hardware
replaced by models: every millisecond of robot time it hands the core the radio frames that
arrived, the GGA sentences the GPS printed, a battery ADC sample every 20 ms, calls
``amz_robot_step`` and feeds the motor output (duty, direction pin, driver enable) to
:class:`~basestation.sim.physics.RobotPhysics`. Replies go back on the air after a processing
delay. Nothing of the robot's behaviour is re-implemented in Python: ramp, clamp, dead-man,
time-to-live, reversal and e-stop are the firmware's.

Time is explicit: :meth:`SimulatedRobot.advance_to` (or :meth:`step`) runs the robot up to
a time on the channel's clock, so runs are deterministic under a fake clock; in-process the
channel advances the robot whenever the base station's chip looks at the air, and
``python -m basestation.sim`` advances it from the wall clock.
"""

from __future__ import annotations

import ctypes
import heapq
import math
import random
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any, Final

from basestation.protocol import BROADCAST_NODE, TelemetryStatus
from basestation.radio.registers import FIFO_SIZE
from basestation.sim.channel import (
    AirFrame,
    AirPort,
    AirSignature,
    Channel,
    Reception,
    aes_key_id,
    airtime_s,
)
from basestation.sim.config import RadioConfig, SimConfig
from basestation.sim.firmware import (
    AmzRobotConfig,
    FirmwareRobot,
    default_robot_config,
    load_library,
)
from basestation.sim.flashed import FlashedRobot
from basestation.sim.gps import GpsNoise, gga_sentence
from basestation.sim.physics import RobotPhysics

TICK_MS: Final = 1  # the Arduino's loop runs at least this often
#: Longer gaps with the robot at rest are skipped rather than simulated tick by tick.
IDLE_SKIP_MS: Final = 5000
BATTERY_PERIOD_MS: Final = 20
WHEEL_PERIOD_MS: Final = 100
#: docs/protocol.md §1 carrier and bit rate registers.
FRF_433_MHZ: Final = 0x6C4000
BITRATE_55K5: Final = 0x0240
SYNC_WORD_1: Final = 0x2D
SENSITIVITY_DBM: Final = -105.0


def status_names(status: int) -> list[str]:
    return [flag.name or "" for flag in TelemetryStatus if status & flag]


@dataclass(frozen=True, slots=True)
class TraceSample:
    """The robot at one instant, for tests and reports (physics truth and firmware view)."""

    time_s: float
    odometer_m: float  # unwrapped along-track position, + = CW
    velocity_mps: float  # physics, signed
    applied_mps: float  # the firmware's ramp output, signed
    duty: int
    direction_cw: bool  # the direction pin
    drive_enabled: bool
    status: int
    battery_v: float  # terminal voltage


@dataclass(frozen=True)
class RobotState:
    """A snapshot for logs and the inspection port."""

    time_s: float
    robot_clock_ms: int
    track_m: float
    odometer_m: float
    side: str  # the thesis side (A N-E, B E-S, C S-W, D W-N), as the agent's grid id
    velocity_mps: float
    applied_velocity_mps: float
    accel_mps2: float
    duty: int
    direction: str
    drive_enabled: bool
    status: int
    status_flags: list[str]
    e_stop_latched: bool
    dead_man: bool
    battery_v: float
    battery_reported_v: float
    state_of_charge: float
    lat_deg: float
    lon_deg: float
    gps_fix: str
    frames_received: int
    frames_answered: int
    frames_dropped: int

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True, order=True, slots=True)
class _Due:
    at_s: float
    order: int
    data: bytes = b""
    rssi_dbm: float = 0.0


FrameHandler = Callable[[float, bytes, float], None]  # (end_s, frame, rssi_dbm)


class FrameRadio:
    """An RFM69 at frame level, set up as docs/protocol.md §1 says: it hears packets on its
    carrier and sync word, drops bad CRCs, filters its node address or broadcast, and decrypts
    only with the same AES key. The robot's radio, and the report's frame-level base station.

    ``on_frame`` gets every accepted frame with the time its last bit arrived; ``advance``
    (the robot's) makes the radio lazy: the in-process channel calls it before anyone else
    looks at the air.
    """

    def __init__(
        self,
        config: RadioConfig,
        on_frame: FrameHandler,
        *,
        advance: Callable[[float], None] | None = None,
    ) -> None:
        self.config = config
        self._on_frame = on_frame
        self._advance = advance
        self.signature = AirSignature(
            frf=FRF_433_MHZ,
            bitrate_raw=BITRATE_55K5,
            sync=bytes([SYNC_WORD_1, config.network_id]),
            crc_on=True,
            variable_length=True,
            aes_key_id=aes_key_id(config.aes_key),
        )
        self.tx_power_dbm = 17.0 if config.high_power else 13.0
        self.port: AirPort | None = None
        self._channel: Channel | None = None
        self._busy_until_s = -math.inf
        self._tx_until_s = -math.inf
        self.frames_dropped = 0

    def connect(self, channel: Channel) -> None:
        self._channel = channel
        self.port = channel.attach(self, lazy=self._advance is not None)

    def advance_to(self, time_s: float) -> None:
        if self._advance is not None:
            self._advance(time_s)

    def airtime_s(self, frame_len: int) -> float:
        return airtime_s(frame_len, aes=self.config.aes_key is not None)

    def receive_air(self, reception: Reception) -> None:
        frame = reception.frame
        if reception.never_sent or not frame.signature.heard_by(self.signature):
            return
        if reception.rssi_dbm < SENSITIVITY_DBM:
            return
        # Half duplex, and one packet at a time.
        if reception.start_s < self._tx_until_s or reception.start_s < self._busy_until_s:
            self.frames_dropped += 1
            return
        self._busy_until_s = reception.end_s
        data = frame.data
        ok = (
            frame.signature.aes_key_id == self.signature.aes_key_id
            and not reception.corrupted
            and not reception.truncated
            and frame.signature.crc_on
            and frame.signature.variable_length
            and 2 <= len(data) <= FIFO_SIZE
            and data[0] == len(data) - 1
            and data[1] in (self.config.node, BROADCAST_NODE)
        )
        if not ok:
            self.frames_dropped += 1
            return
        self._on_frame(reception.end_s, data, reception.rssi_dbm)

    def transmit(self, data: bytes, start_s: float) -> None:
        duration_s = self.airtime_s(len(data))
        self._tx_until_s = start_s + duration_s
        if self.port is None:
            return
        next_id = getattr(self._channel, "next_tx_id", None)
        self.port.transmit(
            AirFrame(
                tx_id=int(next_id()) if next_id is not None else 0,
                data=data,
                start_s=start_s,
                airtime_s=duration_s,
                signature=self.signature,
                tx_power_dbm=self.tx_power_dbm,
            )
        )


class SimulatedRobot:
    """The firmware core on the rail.

    ``channel``: the air to listen and answer on (optional: without one, use
    :meth:`handle_frame` directly). ``start_s``: boot time on the channel's clock (default
    the channel's "now", else 0). ``trace_interval_s``: keep a :class:`TraceSample` that
    often in :attr:`trace` (None: no trace).
    """

    def __init__(
        self,
        config: SimConfig | None = None,
        *,
        channel: Channel | None = None,
        library: ctypes.CDLL | None = None,
        start_s: float | None = None,
        trace_interval_s: float | None = None,
    ) -> None:
        self.config = config if config is not None else SimConfig()
        self._library = library if library is not None else load_library()
        self._firmware_config = self.config.robot_config(default_robot_config(self._library))
        if start_s is None:
            start_s = channel.clock() if channel is not None else 0.0
        self.start_s = float(start_s)
        self._ms = 0
        self.firmware = self._make_firmware()
        self.physics = RobotPhysics(
            self.config.physics,
            self.config.battery,
            odometer_m=self.config.start_track_m,
        )
        seed = self.config.seed
        self._adc_rng = random.Random(seed * 4 + 1)
        self._gps_rng = random.Random(seed * 4 + 2)
        self._gps_fix = self.config.gps.fix
        self._gps_noise = GpsNoise(self.config.gps.model(), self._gps_rng)
        self._gps_period_s = 1.0 / self.config.gps.rate_hz
        self._next_gps_epoch_s = 0.0  # robot time
        self._gps_pending: deque[tuple[float, bytes]] = deque()
        self._rx: list[_Due] = []
        self._rx_lock = threading.Lock()
        self._tx: list[_Due] = []
        self._order = 0
        self._duty_max = max(1, int(self._firmware_config.duty_max))
        self._wheel_last_m = self.physics.wheel_m
        self._wheel_pulses_carry_m = 0.0
        self._last_output_duty = 0
        self._last_direction_cw = True
        self._last_drive_enabled = not self.config.e_stop_latched_at_boot
        self._last_applied_mm_s = 0
        self._last_status = 0
        self.frames_received = 0
        self.frames_answered = 0
        self.trace: list[TraceSample] = []
        self._trace_every_ms = (
            0 if trace_interval_s is None else max(1, round(trace_interval_s * 1000))
        )
        self._advancing = False
        self.radio = FrameRadio(self.config.radio, self._frame_arrived, advance=self.advance_to)
        if channel is not None:
            self.radio.connect(channel)
        self._step_firmware(0)

    def _make_firmware(self) -> FirmwareRobot | FlashedRobot:
        """The firmware this robot runs: the host-built core, or the flashed image itself."""
        latched = self.config.e_stop_latched_at_boot
        if self.config.flashed:
            return FlashedRobot(self._firmware_config, e_stop_latched=latched)
        return FirmwareRobot(
            self._library, config=self._firmware_config, now_ms=0, e_stop_latched=latched
        )

    def close(self) -> None:
        self.firmware.close()

    @property
    def firmware_config(self) -> AmzRobotConfig:
        """The configuration the firmware core runs with (compiled defaults + overrides)."""
        return self._firmware_config

    # --- time ----------------------------------------------------------------------------------

    @property
    def time_s(self) -> float:
        """Now, on the channel's clock."""
        return self.start_s + self._ms / 1000.0

    @property
    def robot_clock_ms(self) -> int:
        """The robot's ``millis()``."""
        return self._ms & 0xFFFFFFFF

    def advance_to(self, time_s: float) -> None:
        """Run the robot up to ``time_s`` (channel clock) in 1 ms loop iterations."""
        if self._advancing:
            return
        self._advancing = True
        try:
            target_ms = math.floor((time_s - self.start_s) * 1000.0 + 1e-6)
            if target_ms - self._ms > IDLE_SKIP_MS and self._idle():
                self._skip_idle(target_ms - 1000)
            while self._ms < target_ms:
                self._tick()
            self._flush_tx(time_s)
        finally:
            self._advancing = False

    def _idle(self) -> bool:
        return (
            self.physics.velocity_mps == 0.0
            and self.physics.throttle_mps < 1e-6
            and self._last_output_duty == 0
            and not self._rx
            and not self._tx
        )

    def _skip_idle(self, new_ms: int) -> None:
        """Jump over a long stretch with the robot at rest and nothing on the air (the first
        access after a pause): only the idle discharge happens in it. The last second before
        the target is then simulated normally, so GPS and battery readings are fresh."""
        skipped_s = (new_ms - self._ms) / 1000.0
        battery = self.config.battery
        self.physics.soc = max(
            0.0,
            self.physics.soc - battery.idle_current_a * skipped_s / (battery.capacity_ah * 3600),
        )
        self.physics.throttle_mps = 0.0
        self._ms = new_ms
        robot_s = new_ms / 1000.0
        self._next_gps_epoch_s = math.ceil(robot_s / self._gps_period_s) * self._gps_period_s
        self._gps_pending.clear()
        self._wheel_last_m = self.physics.wheel_m
        self._step_firmware(new_ms)

    def step(self, dt_s: float) -> None:
        """Run the robot for ``dt_s`` more seconds."""
        if dt_s < 0:
            raise ValueError(f"cannot step back in time ({dt_s} s)")
        self.advance_to(self.time_s + dt_s)

    # --- inputs --------------------------------------------------------------------------------

    def handle_frame(self, frame: bytes, rssi_dbm: float = -60.0) -> bytes:
        """A frame straight into the firmware at the current time, bypassing the air;
        returns the reply (empty when the firmware does not answer)."""
        self.frames_received += 1
        reply = self.firmware.handle_frame(self._ms, frame, round(rssi_dbm))
        self._step_firmware(self._ms)  # "a command is acted on before its answer is sent"
        if reply:
            self.frames_answered += 1
        return reply

    def _frame_arrived(self, end_s: float, data: bytes, rssi_dbm: float) -> None:
        # Called from the UDP channel's receiving thread when the robot runs as a process.
        with self._rx_lock:
            self._order += 1
            heapq.heappush(self._rx, _Due(end_s, self._order, data, rssi_dbm))

    def set_local_stop(self, open_: bool) -> None:
        self.firmware.set_local_stop(open_)

    def set_gps_fix(self, fix: str) -> None:
        """Switch the receiver's fix state (``rtk_fixed``, ``rtk_float``, ``gps``, ...)."""
        gps = replace(self.config.gps, fix=fix, sigma_m=None, correlation_s=None)
        self._gps_fix = fix
        self._gps_noise = GpsNoise(gps.model(), self._gps_rng)

    # --- the loop --------------------------------------------------------------------------------

    def _tick(self) -> None:
        self._ms += TICK_MS
        ms = self._ms
        now_s = self.start_s + ms / 1000.0
        self._gps(now_s - self.start_s, ms)
        while self._rx and self._rx[0].at_s <= now_s:
            with self._rx_lock:
                due = heapq.heappop(self._rx)
            reply = self.handle_frame(due.data, due.rssi_dbm)
            if reply:
                with self._rx_lock:
                    self._order += 1
                at_s = now_s + self.config.radio.processing_delay_s
                heapq.heappush(self._tx, _Due(at_s, self._order, reply))
        self._flush_tx(now_s)
        if ms % BATTERY_PERIOD_MS == 0:
            self.firmware.add_battery_sample(self._adc_counts())
        if self.config.wheel_um_per_pulse and ms % WHEEL_PERIOD_MS == 0:
            self._wheel(ms)
        self._step_firmware(ms)
        self.physics.step(
            TICK_MS / 1000.0,
            duty=self._last_output_duty,
            duty_max=self._duty_max,
            direction_cw=self._last_direction_cw,
            drive_enabled=self._last_drive_enabled,
        )
        if self._trace_every_ms and ms % self._trace_every_ms == 0:
            self.trace.append(self.sample())

    def _step_firmware(self, ms: int) -> None:
        out = self.firmware.step(ms)
        self._last_output_duty = out.duty
        self._last_direction_cw = out.direction == 1
        self._last_drive_enabled = out.drive_enabled
        self._last_applied_mm_s = out.velocity_mm_s
        self._last_status = out.status

    def _flush_tx(self, now_s: float) -> None:
        while self._tx and self._tx[0].at_s <= now_s:
            due = heapq.heappop(self._tx)
            self.radio.transmit(due.data, due.at_s)

    def _adc_counts(self) -> int:
        """analogRead(A0): the terminal voltage through the divider, with noise and the odd
        spike (the thesis's reason for the median filter)."""
        b = self.config.battery
        fw = self._firmware_config
        volts = self.physics.battery_v
        if b.adc_spike_probability and self._adc_rng.random() < b.adc_spike_probability:
            volts -= b.adc_spike_v
        pin_v = volts * fw.battery_divider_den / max(1, fw.battery_divider_num)
        counts = pin_v / (fw.battery_vref_mv / 1000.0) * fw.battery_adc_full_scale
        counts += self._adc_rng.gauss(0.0, b.adc_noise_counts)
        return max(0, min(int(fw.battery_adc_full_scale) - 1, round(counts)))

    def _wheel(self, ms: int) -> None:
        """A hall sensor counting ``wheel_um_per_pulse`` of the wheel's travel per pulse (the
        body's too, but for slip), read every 100 ms."""
        travelled_m = abs(self.physics.wheel_m - self._wheel_last_m)
        self._wheel_last_m = self.physics.wheel_m
        per_pulse_m = self.config.wheel_um_per_pulse / 1e6
        total_m = self._wheel_pulses_carry_m + travelled_m
        pulses = int(total_m / per_pulse_m)
        self._wheel_pulses_carry_m = total_m - pulses * per_pulse_m
        mm_s = pulses * self.config.wheel_um_per_pulse // WHEEL_PERIOD_MS
        self.firmware.set_measured_velocity(ms, min(0xFFFF, mm_s))

    def _gps(self, robot_s: float, ms: int) -> None:
        gps = self.config.gps
        while robot_s >= self._next_gps_epoch_s:
            epoch_s = self._next_gps_epoch_s
            self._next_gps_epoch_s = epoch_s + self._gps_period_s
            model = self._gps_noise.model
            if self._gps_fix == "off":
                continue
            if model.quality == 0:
                sentence = gga_sentence(
                    utc_s_of_day=gps.utc_start_s + epoch_s,
                    lat_deg=None,
                    lon_deg=None,
                    quality=0,
                    satellites=model.satellites,
                    hdop=model.hdop,
                )
            else:
                noise_e, noise_n = self._gps_noise.next(self._gps_period_s)
                east_m, north_m = self.config.rail.xy_at(self.physics.odometer_m)
                lat, lon = self.config.rail.frame.to_lat_lon(east_m + noise_e, north_m + noise_n)
                sentence = gga_sentence(
                    utc_s_of_day=gps.utc_start_s + epoch_s,
                    lat_deg=lat,
                    lon_deg=lon,
                    quality=model.quality,
                    satellites=model.satellites,
                    hdop=model.hdop,
                    altitude_m=gps.altitude_m,
                    differential_age_s=1.0 if model.quality in (2, 4, 5) else None,
                )
            self._gps_pending.append((epoch_s + gps.latency_s, sentence))
        while self._gps_pending and self._gps_pending[0][0] <= robot_s:
            _, sentence = self._gps_pending.popleft()
            self.firmware.feed_gps(ms, sentence)

    # --- outputs --------------------------------------------------------------------------------

    def sample(self) -> TraceSample:
        return TraceSample(
            time_s=self.time_s,
            odometer_m=self.physics.odometer_m,
            velocity_mps=self.physics.velocity_mps,
            applied_mps=self._last_applied_mm_s / 1000.0,
            duty=self._last_output_duty,
            direction_cw=self._last_direction_cw,
            drive_enabled=self._last_drive_enabled,
            status=self._last_status,
            battery_v=self.physics.battery_v,
        )

    @property
    def track_m(self) -> float:
        return self.config.rail.wrap(self.physics.odometer_m)

    @property
    def velocity_mps(self) -> float:
        return self.physics.velocity_mps

    @property
    def e_stop_latched(self) -> bool:
        return self.firmware.e_stop_latched

    @property
    def status(self) -> int:
        return self.firmware.status(self._ms)

    def state(self) -> RobotState:
        status = self.status
        lat, lon = self.config.rail.point_at(self.physics.odometer_m)
        return RobotState(
            time_s=round(self.time_s, 3),
            robot_clock_ms=self.robot_clock_ms,
            track_m=round(self.track_m, 4),
            odometer_m=round(self.physics.odometer_m, 4),
            side=self.config.rail.side_at(self.physics.odometer_m),
            velocity_mps=round(self.physics.velocity_mps, 4),
            applied_velocity_mps=self._last_applied_mm_s / 1000.0,
            accel_mps2=round(self.physics.accel_mps2, 4),
            duty=self._last_output_duty,
            direction="cw" if self._last_direction_cw else "ccw",
            drive_enabled=self._last_drive_enabled,
            status=status,
            status_flags=status_names(status),
            e_stop_latched=self.firmware.e_stop_latched,
            dead_man=bool(status & TelemetryStatus.DEAD_MAN),
            battery_v=round(self.physics.battery_v, 3),
            battery_reported_v=self.firmware.battery_10mv / 100.0,
            state_of_charge=round(self.physics.soc, 5),
            lat_deg=round(lat, 8),
            lon_deg=round(lon, 8),
            gps_fix=self._gps_fix,
            frames_received=self.frames_received,
            frames_answered=self.frames_answered,
            frames_dropped=self.radio.frames_dropped,
        )
