"""Build the robot the agent drives, as the configuration says (``AGENT_ROBOT``)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from basestation.config import AgentConfig, ConfigError
from basestation.robot import (
    Robot,
    RobotIdentity,
    RobotLimits,
    RobotLinkError,
    SimpleSimulatedRobot,
)

logger = logging.getLogger(__name__)

# A lost config frame or answer is retried this many times before the agent starts without
# the robot's confirmation (a robot switched off now still has its compiled-in limits).
CONFIGURE_ATTEMPTS = 3
# The limits are sent, and the firmware asked its build, once, at start-up, before any tick:
# nothing waits on the answers but the start itself, so a robot busy for a moment (or a loaded
# simulator) gets longer than a tick.
CONFIGURE_REPLY_TIMEOUT_S = 0.25


class RadioRobot:
    """The radio link plus the SPI device under it, closed together."""

    def __init__(self, link: Any, radio: Any, spi: Any) -> None:
        self.link = link
        self.radio = radio
        self.spi = spi
        # What the robot confirmed of the agent's limits at start-up (None: no answer).
        self.limits: RobotLimits | None = None
        # Which firmware the robot said it runs, at start-up (None: no answer).
        self.identity: RobotIdentity | None = None

    def exchange(self, command: Any, now_s: float) -> Any:
        return self.link.exchange(command, now_s)

    def __getattr__(self, name: str) -> Any:  # stats(), release_estop(), last_telemetry, …
        return getattr(self.link, name)

    def close(self) -> None:
        try:
            self.radio.close()
        finally:
            close = getattr(self.spi, "close", None)
            if close is not None:
                close()


def reply_timeout_s(control_hz: float) -> float:
    """How long a tick waits for the robot's answer: the link's 25 ms, or less at rates above
    24 Hz so that the command (3 ms on air), the wait and the rest of the tick fit one
    period. At 50 Hz: 12 ms, for a reply of 5.5 ms on air plus the robot's turnaround
    (docs/protocol.md §5); a tick whose answer is lost still ends before the next is due."""
    from basestation.radio.link import DEFAULT_REPLY_TIMEOUT_S

    return min(DEFAULT_REPLY_TIMEOUT_S, 0.6 / control_hz)


def build_robot(config: AgentConfig) -> Robot:
    if config.robot == "simple":
        return SimpleSimulatedRobot(
            max_velocity_mps=config.max_velocity_mps,
            max_accel_mps2=config.max_accel_mps2,
            rail_length_m=config.rail_length_m,
        )
    # Imported here: the radio stack is not needed by the simple model (nor on a laptop
    # without spidev).
    from basestation.radio.rfm69 import open_spidev
    from basestation.telemetry.rail import Rail, RailConfigError

    try:
        rail = Rail.configured(config.rail_file)
    except RailConfigError as exc:
        raise ConfigError(f"AGENT_RAIL_FILE: {exc}") from exc
    if config.robot == "radio":
        spi: Any = open_spidev(config.spi_bus, config.spi_device)
    else:
        spi = _simulated_spi(config, rail)
    return radio_robot(config, spi, rail)


def radio_robot(
    config: AgentConfig,
    spi: Any,
    rail: Any,
    *,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> RadioRobot:
    """The robot behind the RFM69 on ``spi``, its limits sent and its firmware asked, with the
    driver's waits on ``clock``/``sleep`` (a simulator's clock in simulated time)."""
    from basestation.radio.link import RadioRobotLink
    from basestation.radio.rfm69 import RFM69, RadioError, RadioSettings, parse_aes_key

    aes_key = parse_aes_key(config.radio_aes_key) if config.radio_aes_key else None
    try:
        radio = RFM69(spi, RadioSettings(aes_key=aes_key), clock=clock, sleep=sleep)
        radio.begin()
    except RadioError as exc:
        raise ConfigError(f"the robot's radio did not start: {exc}") from exc
    link = RadioRobotLink(radio, rail=rail, reply_timeout_s=reply_timeout_s(config.control_hz))
    robot = RadioRobot(link, radio, spi)
    try:
        robot.limits = _configure(link, config)
    except ConfigError:
        robot.close()
        raise
    robot.identity = _identify(link)
    return robot


def _simulated_spi(config: AgentConfig, rail: Any) -> Any:
    """The emulated chip of ``AGENT_ROBOT=sim``, ``sim-flashed`` or ``sim-udp``, with the robot
    in this process on the agent's rail, or in its own."""
    from basestation.sim import (
        SimConfig,
        SimConfigError,
        SimulatedSpiConfig,
        make_simulated_spi,
    )
    from basestation.sim.firmware import FirmwareError

    if config.robot in ("sim", "sim-flashed"):
        try:
            sim = SimConfig.load(config.sim_config) if config.sim_config else SimConfig()
            # The simulated robot drives the rail the agent projects onto: one file for both.
            sim = replace(sim, rail=rail, flashed=sim.flashed or config.robot == "sim-flashed")
        except SimConfigError as exc:
            raise ConfigError(f"AGENT_SIM_CONFIG: {exc}") from exc
        try:
            return make_simulated_spi(SimulatedSpiConfig(sim=sim))
        except FirmwareError as exc:
            raise ConfigError(f"AGENT_ROBOT={config.robot}: {exc}") from exc
    return make_simulated_spi(
        SimulatedSpiConfig(
            transport="udp", base_port=config.sim_base_port, robot_port=config.sim_robot_port
        )
    )


def _identify(link: Any) -> RobotIdentity | None:
    """Which firmware the robot runs, for every run's record; None when it does not say."""
    for attempt in range(1, CONFIGURE_ATTEMPTS + 1):
        try:
            # As long a wait as the limits': only the start waits on it.
            identity: RobotIdentity = link.identify(reply_timeout_s=CONFIGURE_REPLY_TIMEOUT_S)
        except RobotLinkError as exc:
            if attempt == CONFIGURE_ATTEMPTS:
                logger.warning(
                    "robot did not report its firmware (%s): runs record it as unknown; a "
                    "firmware older than the identity frame does not answer",
                    exc,
                )
            continue
        logger.info("robot firmware: build %s", identity.build_id or "(no id)")
        return identity
    return None


def _configure(link: Any, config: AgentConfig) -> RobotLimits | None:
    """Send the agent's limits to the robot; refuse a limit above the robot's hard maximum."""
    limits: RobotLimits | None = None
    for attempt in range(1, CONFIGURE_ATTEMPTS + 1):
        try:
            limits = link.configure(
                max_velocity_mps=config.max_velocity_mps,
                accel_mps2=config.max_accel_mps2,
                reply_timeout_s=CONFIGURE_REPLY_TIMEOUT_S,
            )
            break
        except RobotLinkError as exc:
            if attempt == CONFIGURE_ATTEMPTS:
                # The robot may be off or out of range now; its compiled-in limits still hold.
                logger.warning(
                    "robot did not confirm its limits (%s); it keeps its built-in ones", exc
                )
    if limits is None:
        return None
    logger.info(
        "robot limits applied: %.2f m/s, %.2f m/s²; hard maximum %s",
        limits.max_velocity_mps,
        limits.max_accel_mps2,
        "not reported"
        if limits.hard_max_velocity_mps is None
        else f"{limits.hard_max_velocity_mps:g} m/s",
    )
    check_within_hard_max(config, limits)
    return limits


def check_within_hard_max(config: AgentConfig, limits: RobotLimits) -> None:
    """``ConfigError`` when the agent's velocity limit is above the robot's hard maximum:
    runs the agent would accept could never be driven as booked."""
    hard_max = limits.hard_max_velocity_mps
    # The wire carries whole mm/s: compare at that resolution.
    if hard_max is not None and round(config.max_velocity_mps * 1000) > round(hard_max * 1000):
        raise ConfigError(
            f"AGENT_MAX_VELOCITY_MPS={config.max_velocity_mps:g} is above the robot's hard "
            f"maximum {hard_max:g} m/s (AMZ_HARD_MAX_VELOCITY_MM_S in its firmware)"
        )
