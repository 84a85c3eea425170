"""The base station ↔ robot wire protocol (docs/protocol.md), version 1.

Pure Python; shares nothing with the firmware but the document and
``tests/vectors/protocol.json``.
"""

from basestation.protocol.codec import (
    decode_command,
    decode_config,
    decode_frame,
    decode_telemetry,
    encode_command,
    encode_config,
    encode_frame,
    encode_telemetry,
)
from basestation.protocol.errors import FRAME_ERROR_KINDS, FrameError, FrameErrorKind
from basestation.protocol.frames import (
    ACCEL_LIMIT_MM_S2,
    BASESTATION_NODE,
    BROADCAST_NODE,
    COMMAND_FRAME_SIZE,
    CONFIG_FRAME_SIZE,
    DEAD_MAN_MS,
    MAX_FRAME_SIZE,
    PROTOCOL_VERSION,
    ROBOT_NODE,
    TELEMETRY_FRAME_SIZE,
    VELOCITY_LIMIT_MM_S,
    CommandFlag,
    CommandFrame,
    ConfigFrame,
    Direction,
    FixQuality,
    Frame,
    FrameType,
    TelemetryFrame,
    TelemetryStatus,
)

__all__ = [
    "ACCEL_LIMIT_MM_S2",
    "BASESTATION_NODE",
    "BROADCAST_NODE",
    "COMMAND_FRAME_SIZE",
    "CONFIG_FRAME_SIZE",
    "DEAD_MAN_MS",
    "FRAME_ERROR_KINDS",
    "MAX_FRAME_SIZE",
    "PROTOCOL_VERSION",
    "ROBOT_NODE",
    "TELEMETRY_FRAME_SIZE",
    "VELOCITY_LIMIT_MM_S",
    "CommandFlag",
    "CommandFrame",
    "ConfigFrame",
    "Direction",
    "FixQuality",
    "Frame",
    "FrameError",
    "FrameErrorKind",
    "FrameType",
    "TelemetryFrame",
    "TelemetryStatus",
    "decode_command",
    "decode_config",
    "decode_frame",
    "decode_telemetry",
    "encode_command",
    "encode_config",
    "encode_frame",
    "encode_telemetry",
]
