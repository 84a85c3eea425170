"""The simulator: the robot's real firmware core on simulated rail physics, and an RFM69
emulated at the SPI register level for the base station's driver (docs/simulator.md).

The agent's one entry point is :func:`make_simulated_spi`; the rest is for tests and tools.
"""

from basestation.sim.channel import (
    AirFrame,
    AirSignature,
    Channel,
    InProcessChannel,
    Reception,
    UdpChannel,
    airtime_s,
)
from basestation.sim.clock import Clock, FakeClock
from basestation.sim.config import GpsConfig, RadioConfig, SimConfig, SimConfigError
from basestation.sim.firmware import FirmwareError, FirmwareRobot, load_library
from basestation.sim.physics import BatteryConfig, PhysicsConfig, RobotPhysics
from basestation.sim.rfm69 import EmulatedRFM69, ModeTimings, SpiDevice
from basestation.sim.robot import FrameRadio, RobotState, SimulatedRobot, TraceSample
from basestation.sim.spi import SimulatedSpi, SimulatedSpiConfig, make_simulated_spi

__all__ = [
    "AirFrame",
    "AirSignature",
    "BatteryConfig",
    "Channel",
    "Clock",
    "EmulatedRFM69",
    "FakeClock",
    "FirmwareError",
    "FirmwareRobot",
    "FrameRadio",
    "GpsConfig",
    "InProcessChannel",
    "ModeTimings",
    "PhysicsConfig",
    "RadioConfig",
    "Reception",
    "RobotPhysics",
    "RobotState",
    "SimConfig",
    "SimConfigError",
    "SimulatedRobot",
    "SimulatedSpi",
    "SimulatedSpiConfig",
    "SpiDevice",
    "TraceSample",
    "UdpChannel",
    "airtime_s",
    "load_library",
    "make_simulated_spi",
]
