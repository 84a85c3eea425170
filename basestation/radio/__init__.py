"""The base station's radio: an RFM69 driver over SPI and the robot link on top of it."""

from basestation.radio.link import (
    DEFAULT_LINK_DOWN_AFTER_S,
    DEFAULT_LOSS_WINDOW,
    DEFAULT_REPLY_TIMEOUT_S,
    FrameRadio,
    LinkStats,
    RadioRobotLink,
    RadioTelemetry,
)
from basestation.radio.rfm69 import (
    RFM69,
    RadioError,
    RadioSettings,
    SpiDevice,
    open_spidev,
    parse_aes_key,
)

__all__ = [
    "DEFAULT_LINK_DOWN_AFTER_S",
    "DEFAULT_LOSS_WINDOW",
    "DEFAULT_REPLY_TIMEOUT_S",
    "RFM69",
    "FrameRadio",
    "LinkStats",
    "RadioError",
    "RadioRobotLink",
    "RadioSettings",
    "RadioTelemetry",
    "SpiDevice",
    "open_spidev",
    "parse_aes_key",
]
