"""The simulated SPI device the agent opens instead of ``spidev.SpiDev``.

``make_simulated_spi(SimulatedSpiConfig(...))`` returns a :class:`SimulatedSpi`: the base
station's :class:`~basestation.sim.rfm69.EmulatedRFM69` on an air whose other end is the
simulated robot, either in this process (the robot advances whenever the chip is accessed) or
a separate ``python -m basestation.sim`` process reached over UDP on 127.0.0.1.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Final, Literal

from basestation.sim.channel import InProcessChannel, UdpChannel
from basestation.sim.clock import Clock, FakeClock
from basestation.sim.config import SimConfig
from basestation.sim.rfm69 import EmulatedRFM69, ModeTimings
from basestation.sim.robot import SimulatedRobot

#: Loopback UDP ports of the two radios and the robot process's inspection port.
DEFAULT_BASE_PORT: Final = 47001
DEFAULT_ROBOT_PORT: Final = 47002
DEFAULT_INSPECT_PORT: Final = 47003


@dataclass(frozen=True)
class SimulatedSpiConfig:
    """How to wire the base station's emulated radio.

    ``transport="inprocess"``: the robot (``sim``) lives in this process on ``clock`` (default
    ``time.monotonic``; pass a :class:`~basestation.sim.clock.FakeClock` for deterministic
    tests). ``transport="udp"``: the robot is a ``python -m basestation.sim`` process whose
    radio listens on ``robot_port``; this radio binds ``base_port`` (both on 127.0.0.1).
    ``latency_s``/``loss_probability``/``seed`` shape the air as this end hears it.
    """

    transport: Literal["inprocess", "udp"] = "inprocess"
    sim: SimConfig | None = None
    clock: Clock | None = None
    base_port: int = DEFAULT_BASE_PORT
    robot_port: int = DEFAULT_ROBOT_PORT
    latency_s: float = 0.0
    loss_probability: float = 0.0
    seed: int = 0
    timings: ModeTimings | None = None
    trace_interval_s: float | None = None  # in process: keep the robot's trace this often


class SimulatedSpi:
    """A ``spidev``-like device: ``xfer2``/``close`` go to the emulated RFM69.

    The parts stay reachable for tests and for the simulator's own tools: :attr:`chip`,
    :attr:`channel` (``cut()``/``restore()`` to lose the link) and, in process, :attr:`robot`.
    """

    def __init__(
        self,
        chip: EmulatedRFM69,
        channel: InProcessChannel | UdpChannel,
        robot: SimulatedRobot | None = None,
    ) -> None:
        self.chip = chip
        self.channel = channel
        self.robot = robot
        # spidev attributes a driver may set; the emulation has no bus timing.
        self.max_speed_hz = 4_000_000
        self.mode = 0
        self.bits_per_word = 8

    def xfer2(self, data: list[int]) -> list[int]:
        return self.chip.xfer2(data)

    @property
    def dio0(self) -> bool:
        return self.chip.dio0

    def advance_to(self, time_s: float) -> None:
        """In process with a fake clock: move the clock and run the robot up to ``time_s``."""
        clock = self.channel.clock
        if isinstance(clock, FakeClock):
            clock.set(time_s)
        if isinstance(self.channel, InProcessChannel):
            self.channel.advance(time_s)

    def close(self) -> None:
        self.chip.close()
        if isinstance(self.channel, UdpChannel):
            self.channel.close()
        if self.robot is not None:
            self.robot.close()

    def __enter__(self) -> SimulatedSpi:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def make_simulated_spi(config: SimulatedSpiConfig | None = None) -> SimulatedSpi:
    """The base station's simulated SPI device (see :class:`SimulatedSpiConfig`)."""
    config = config if config is not None else SimulatedSpiConfig()
    if config.transport == "inprocess":
        clock = config.clock if config.clock is not None else time.monotonic
        channel = InProcessChannel(
            clock=clock,
            latency_s=config.latency_s,
            loss_probability=config.loss_probability,
            seed=config.seed,
        )
        robot = SimulatedRobot(
            config.sim, channel=channel, start_s=clock(), trace_interval_s=config.trace_interval_s
        )
        chip = EmulatedRFM69(channel=channel, timings=config.timings, seed=config.seed, name="bs")
        return SimulatedSpi(chip, channel, robot)
    if config.transport == "udp":
        if config.sim is not None:
            raise ValueError(
                "with transport='udp' the robot is configured in its own process "
                "(python -m basestation.sim --config ...)"
            )
        udp = UdpChannel(
            local_port=config.base_port,
            peer_port=config.robot_port,
            clock=config.clock,
            latency_s=config.latency_s,
            loss_probability=config.loss_probability,
            seed=config.seed,
        )
        chip = EmulatedRFM69(channel=udp, timings=config.timings, seed=config.seed, name="bs")
        return SimulatedSpi(chip, udp)
    raise ValueError(f"transport {config.transport!r} is neither 'inprocess' nor 'udp'")
