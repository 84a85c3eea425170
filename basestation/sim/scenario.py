"""Deterministic runs of the simulated robot with a frame-level base station.

:class:`Bench` puts a :class:`~basestation.sim.robot.SimulatedRobot` and a frame-level base
station radio on an in-process channel with a fake clock, and sends commands the way the
agent does (one command frame per 50 ms tick, telemetry back). The stop and velocity tests of
the thesis (chapter 4) are functions over a bench; ``python -m basestation.sim.report`` and the
tests both use them.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Final, Literal

from basestation.protocol import (
    CommandFlag,
    CommandFrame,
    ConfigAckFrame,
    ConfigFrame,
    Direction,
    FrameError,
    TelemetryFrame,
    decode_frame,
    encode_command,
    encode_config,
)
from basestation.sim.channel import InProcessChannel
from basestation.sim.clock import FakeClock
from basestation.sim.config import GpsConfig, SimConfig
from basestation.sim.robot import FrameRadio, SimulatedRobot, TraceSample

TICK_S: Final = 0.05  # the agent's 20 Hz control tick
#: One PWM duty step of the default build: 8333 mm/s / 255.
DUTY_STEP_MPS: Final = 8.333 / 255

NO_FLAGS: Final = CommandFlag(0)

StopKind = Literal["link_cut", "commanded", "e_stop"]


@dataclass
class Bench:
    """Robot + channel + frame-level base station on one fake clock."""

    robot: SimulatedRobot
    channel: InProcessChannel
    clock: FakeClock
    base: FrameRadio
    telemetry: list[tuple[float, TelemetryFrame]]
    configs: list[ConfigAckFrame]  # the robot's answers to config frames
    seq: int = 0

    @classmethod
    def create(
        cls,
        config: SimConfig | None = None,
        *,
        trace_interval_s: float | None = 0.001,
        loss_probability: float = 0.0,
        latency_s: float = 0.0,
    ) -> Bench:
        config = config if config is not None else SimConfig()
        clock = FakeClock(0.0)
        channel = InProcessChannel(
            clock=clock,
            loss_probability=loss_probability,
            latency_s=latency_s,
            seed=config.seed,
        )
        robot = SimulatedRobot(config, channel=channel, trace_interval_s=trace_interval_s)
        telemetry: list[tuple[float, TelemetryFrame]] = []
        configs: list[ConfigAckFrame] = []

        def on_frame(end_s: float, data: bytes, rssi_dbm: float) -> None:
            try:
                frame = decode_frame(data)
            except FrameError:
                return
            if isinstance(frame, TelemetryFrame):
                telemetry.append((end_s, frame))
            elif isinstance(frame, ConfigAckFrame):
                configs.append(frame)

        radio = replace(config.radio, node=config.radio.base_node, base_node=config.radio.node)
        base = FrameRadio(radio, on_frame)
        base.connect(channel)
        return cls(robot, channel, clock, base, telemetry, configs)

    @property
    def now_s(self) -> float:
        return self.clock.now_s

    def _next_seq(self) -> int:
        self.seq = (self.seq + 1) & 0xFFFF
        return self.seq

    def send(self, frame: bytes) -> None:
        self.base.transmit(frame, self.clock.now_s)

    def send_command(
        self,
        velocity_mps: float,
        direction: Direction = Direction.CW,
        *,
        flags: CommandFlag = NO_FLAGS,
        ttl_ms: int = 500,
    ) -> None:
        self.send(
            encode_command(
                CommandFrame(
                    seq=self._next_seq(),
                    velocity_mm_s=round(velocity_mps * 1000),
                    direction=direction,
                    flags=flags,
                    ttl_ms=ttl_ms,
                    to_node=self.robot.config.radio.node,
                    from_node=self.robot.config.radio.base_node,
                )
            )
        )

    def send_config(self, max_velocity_mps: float, accel_mps2: float) -> None:
        self.send(
            encode_config(
                ConfigFrame(
                    seq=self._next_seq(),
                    max_velocity_mm_s=round(max_velocity_mps * 1000),
                    accel_mm_s2=round(accel_mps2 * 1000),
                    to_node=self.robot.config.radio.node,
                    from_node=self.robot.config.radio.base_node,
                )
            )
        )
        self.advance(TICK_S)

    def advance(self, dt_s: float) -> None:
        self.clock.advance(dt_s)
        self.channel.advance(self.clock.now_s)

    def drive(
        self,
        duration_s: float,
        velocity_mps: float | None,
        direction: Direction = Direction.CW,
        *,
        flags: CommandFlag = NO_FLAGS,
        tick_s: float = TICK_S,
        ttl_ms: int = 500,
    ) -> None:
        """One command per tick for ``duration_s`` (``velocity_mps`` None: send nothing);
        ``tick_s`` is the agent's control period (0.02 at 50 Hz)."""
        ticks = max(0, round(duration_s / tick_s))
        for _ in range(ticks):
            if velocity_mps is not None:
                self.send_command(velocity_mps, direction, flags=flags, ttl_ms=ttl_ms)
            self.advance(tick_s)

    def trace_since(self, time_s: float) -> list[TraceSample]:
        return [s for s in self.robot.trace if s.time_s >= time_s]


# --- stop tests (thesis §4.5) -------------------------------------------------------------------


@dataclass(frozen=True)
class StopResult:
    kind: StopKind
    commanded_mps: float
    speed_at_stop_mps: float  # physics, when the link was cut / the stop was sent
    distance_m: float
    time_s: float  # from the cut / stop to rest
    bound_m: float  # what the model predicts at most
    max_decel_mps2: float  # largest deceleration seen (from physics velocity differences)


def stop_test(
    kind: StopKind,
    velocity_mps: float,
    *,
    config: SimConfig | None = None,
    settle_s: float = 2.0,
) -> StopResult:
    """Drive CW at ``velocity_mps`` until steady, then stop by cutting the link (dead-man),
    by commanding 0, or by e-stop; measure distance and time to rest from physics."""
    bench = Bench.create(config)
    fw = bench.robot.firmware_config
    if velocity_mps * 1000 > fw.max_velocity_mm_s:
        bench.send_config(velocity_mps, fw.accel_mm_s2 / 1000)
    ramp_s = velocity_mps / (fw.accel_mm_s2 / 1000)
    bench.drive(ramp_s + settle_s, velocity_mps)
    t0 = bench.now_s
    x0 = bench.robot.physics.odometer_m
    v0 = bench.robot.physics.velocity_mps
    physics = bench.robot.config.physics
    if kind == "link_cut":
        bench.channel.cut()
        decel = max(fw.accel_mm_s2, fw.stop_decel_mm_s2) / 1000
        bound = physics.stopping_distance_bound_m(v0, decel, fw.dead_man_ms / 1000)
    elif kind == "commanded":
        bound = physics.stopping_distance_bound_m(v0, fw.accel_mm_s2 / 1000, TICK_S)
    else:
        bound = physics.e_stop_distance_m(v0) + v0 * TICK_S
    limit_s = 5.0 + v0 * 4
    while bench.now_s - t0 < limit_s:
        if kind == "commanded":
            bench.drive(TICK_S, 0.0)
        elif kind == "e_stop":
            bench.drive(TICK_S, 0.0, flags=CommandFlag.E_STOP)
        else:
            bench.drive(TICK_S, velocity_mps)  # into the cut link: nobody hears it
        if bench.robot.physics.velocity_mps == 0.0:
            break
    trace = bench.trace_since(t0)
    stopped = next((s for s in trace if s.velocity_mps == 0.0), trace[-1])
    decel = max(
        (
            max(0.0, (a.velocity_mps - b.velocity_mps) / (b.time_s - a.time_s))
            for a, b in _pairs(trace)
        ),
        default=0.0,
    )
    bench.robot.close()
    return StopResult(
        kind=kind,
        commanded_mps=velocity_mps,
        speed_at_stop_mps=v0,
        distance_m=stopped.odometer_m - x0,
        time_s=stopped.time_s - t0,
        bound_m=bound,
        max_decel_mps2=decel,
    )


def _pairs(samples: list[TraceSample]) -> Iterable[tuple[TraceSample, TraceSample]]:
    return itertools.pairwise(samples)


# --- velocity tests (thesis §4.2) ---------------------------------------------------------------


@dataclass(frozen=True)
class VelocityResult:
    fix: str
    commanded_mps: float
    reported_mps: float  # mean of the telemetry's velocity_mm_s over the hold
    gps_mps: float  # least-squares slope of the GPS along-track position over the hold
    true_mps: float  # physics, mean over the hold
    gps_sigma_mps: float  # expected standard deviation of gps_mps from the noise model
    window_sigma_mps: float  # scatter of 1 s GPS speeds (what a live chart would show)
    fixes: int

    @property
    def gps_minus_reported_mps(self) -> float:
        return self.gps_mps - self.reported_mps

    @property
    def gps_minus_true_mps(self) -> float:
        return self.gps_mps - self.true_mps


TIMESTAMP_JITTER_S: Final = TICK_S / math.sqrt(12)  # a fix is seen up to one tick late


def velocity_test(
    fix: str,
    velocity_mps: float,
    *,
    config: SimConfig | None = None,
    hold_s: float = 20.0,
    settle_s: float = 2.0,
) -> VelocityResult:
    """Hold ``velocity_mps`` CW and compare the speed the robot reports with the speed its GPS
    positions (in the same telemetry frames) give, as the base station would compute it."""
    config = config if config is not None else SimConfig()
    config = replace(config, gps=replace(config.gps, fix=fix))
    bench = Bench.create(config)
    fw = bench.robot.firmware_config
    if velocity_mps * 1000 > fw.max_velocity_mm_s:
        bench.send_config(velocity_mps, fw.accel_mm_s2 / 1000)
    bench.drive(velocity_mps / (fw.accel_mm_s2 / 1000) + settle_s, velocity_mps)
    t0 = bench.now_s
    first = len(bench.telemetry)
    bench.drive(hold_s, velocity_mps)
    frames = bench.telemetry[first:]
    rail = bench.robot.config.rail
    reported = sum(f.velocity_mm_s for _, f in frames) / len(frames) / 1000
    # Each fix once, timed by the first frame that carries it (what the base station sees).
    points: list[tuple[float, float]] = []
    last: tuple[int, int] | None = None
    for t, f in frames:
        if (f.lat_e7, f.lon_e7) != last and f.fix_quality:
            last = (f.lat_e7, f.lon_e7)
            points.append((t, rail.project(f.lat_e7 / 1e7, f.lon_e7 / 1e7).track_m))
    unwrapped = _unwrap([p for _, p in points], rail.length_m)
    times = [t for t, _ in points]
    gps = _slope(times, unwrapped)
    windows = []
    for i in range(len(times)):
        j = next((k for k in range(i, len(times)) if times[k] - times[i] >= 1.0), None)
        if j is None:
            break
        windows.append(_slope(times[i : j + 1], unwrapped[i : j + 1]))
    mean_w = sum(windows) / len(windows)
    window_sigma = math.sqrt(sum((w - mean_w) ** 2 for w in windows) / max(1, len(windows) - 1))
    trace = bench.trace_since(t0)
    true = sum(s.velocity_mps for s in trace) / len(trace)
    sigma = _slope_sigma(config.gps, times, velocity_mps)
    bench.robot.close()
    return VelocityResult(
        fix=fix,
        commanded_mps=velocity_mps,
        reported_mps=reported,
        gps_mps=gps,
        true_mps=true,
        gps_sigma_mps=sigma,
        window_sigma_mps=window_sigma,
        fixes=len(points),
    )


def _unwrap(track: list[float], length_m: float) -> list[float]:
    out: list[float] = []
    offset = 0.0
    for i, value in enumerate(track):
        if i and value + offset - out[-1] < -length_m / 2:
            offset += length_m
        elif i and value + offset - out[-1] > length_m / 2:
            offset -= length_m
        out.append(value + offset)
    return out


def _slope(times: list[float], values: list[float]) -> float:
    n = len(times)
    mt = sum(times) / n
    mv = sum(values) / n
    sxx = sum((t - mt) ** 2 for t in times)
    return sum((t - mt) * (v - mv) for t, v in zip(times, values, strict=True)) / sxx


def _slope_sigma(gps: GpsConfig, times: list[float], speed_mps: float) -> float:
    """Expected standard deviation of the least-squares speed from the noise model: the slope
    is sum(w_i x_i) with w_i = (t_i - mean t) / Sxx, so its variance is
    sum_ij w_i w_j sigma^2 exp(-|t_i - t_j| / tau) (white noise: sigma / sqrt(Sxx)), plus the
    timestamp jitter (a fix is seen up to one tick after it arrives)."""
    model = gps.model()
    mt = sum(times) / len(times)
    sxx = sum((t - mt) ** 2 for t in times)
    weights = [(t - mt) / sxx for t in times]
    if model.correlation_s > 0:
        variance = 0.0
        for wi, ti in zip(weights, times, strict=True):
            for wj, tj in zip(weights, times, strict=True):
                variance += wi * wj * math.exp(-abs(ti - tj) / model.correlation_s)
        noise = model.sigma_m * math.sqrt(max(0.0, variance))
    else:
        noise = model.sigma_m / math.sqrt(sxx)
    jitter = speed_mps * TIMESTAMP_JITTER_S / math.sqrt(sxx)
    return math.hypot(noise, jitter)
