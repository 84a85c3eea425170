"""Build the robot the agent drives, as the configuration says (``AGENT_ROBOT``)."""

from __future__ import annotations

import logging
from typing import Any

from basestation.config import AgentConfig, ConfigError
from basestation.robot import Robot, RobotLinkError, SimpleSimulatedRobot

logger = logging.getLogger(__name__)


class RadioRobot:
    """The radio link plus the SPI device under it, closed together."""

    def __init__(self, link: Any, radio: Any, spi: Any) -> None:
        self.link = link
        self.radio = radio
        self.spi = spi

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


def build_robot(config: AgentConfig) -> Robot:
    if config.robot == "simple":
        return SimpleSimulatedRobot(
            max_velocity_mps=config.max_velocity_mps,
            max_accel_mps2=config.max_accel_mps2,
            rail_length_m=config.rail_length_m,
        )
    # Imported here: the radio stack is not needed by the simple model (nor on a laptop
    # without spidev).
    from basestation.radio.link import RadioRobotLink
    from basestation.radio.rfm69 import RFM69, RadioError, RadioSettings, open_spidev, parse_aes_key
    from basestation.telemetry.rail import Rail, RailConfigError

    try:
        rail = Rail.from_file(config.rail_file) if config.rail_file else Rail.default()
    except RailConfigError as exc:
        raise ConfigError(f"AGENT_RAIL_FILE: {exc}") from exc
    aes_key = parse_aes_key(config.radio_aes_key) if config.radio_aes_key else None
    if config.robot == "radio":
        spi: Any = open_spidev(config.spi_bus, config.spi_device)
    else:
        from basestation.sim import SimConfig, SimulatedSpiConfig, make_simulated_spi

        if config.robot == "sim":
            # The simulated robot drives the rail the agent projects onto: one file for both.
            spi = make_simulated_spi(SimulatedSpiConfig(sim=SimConfig(rail=rail)))
        else:
            spi = make_simulated_spi(
                SimulatedSpiConfig(
                    transport="udp",
                    base_port=config.sim_base_port,
                    robot_port=config.sim_robot_port,
                )
            )
    try:
        radio = RFM69(spi, RadioSettings(aes_key=aes_key))
        radio.begin()
    except RadioError as exc:
        raise ConfigError(f"the robot's radio did not start: {exc}") from exc
    link = RadioRobotLink(radio, rail=rail)
    try:
        applied = link.configure(
            max_velocity_mps=config.max_velocity_mps, accel_mps2=config.max_accel_mps2
        )
        logger.info("robot limits applied: %.2f m/s, %.2f m/s²", *applied)
    except RobotLinkError as exc:
        # The robot may be off or out of range now; its own compiled-in limits still hold.
        logger.warning("robot did not confirm its limits (%s); it keeps its built-in ones", exc)
    return RadioRobot(link, radio, spi)
