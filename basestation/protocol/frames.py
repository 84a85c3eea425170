"""Frame types of the base station ↔ robot wire protocol (docs/protocol.md)."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Final

PROTOCOL_VERSION: Final = 1

BASESTATION_NODE: Final = 1
ROBOT_NODE: Final = 2
BROADCAST_NODE: Final = 255

HEADER_SIZE: Final = 6
COMMAND_FRAME_SIZE: Final = 14
TELEMETRY_FRAME_SIZE: Final = 31
CONFIG_FRAME_SIZE: Final = 12
CONFIG_ACK_FRAME_SIZE: Final = 14
IDENTIFY_FRAME_SIZE: Final = 8
IDENTITY_FRAME_SIZE: Final = 47
#: Bytes of the build identifier on the wire (printable ASCII, NUL-padded).
BUILD_ID_SIZE: Final = 16
MAX_FRAME_SIZE: Final = 66

#: The wire limit for a commanded or configured speed; the robot clamps further.
VELOCITY_LIMIT_MM_S: Final = 10_000
ACCEL_LIMIT_MM_S2: Final = 10_000
LAT_LIMIT_E7: Final = 900_000_000
LON_LIMIT_E7: Final = 1_800_000_000
#: The robot's dead-man: a command is never fresh for longer than this.
DEAD_MAN_MS: Final = 500


class FrameType(enum.IntEnum):
    COMMAND = 1
    TELEMETRY = 2
    CONFIG = 3
    CONFIG_ACK = 4
    IDENTIFY = 5
    IDENTITY = 6


class Direction(enum.IntEnum):
    CCW = 0
    CW = 1


class FixQuality(enum.IntEnum):
    NONE = 0
    GPS = 1
    DGPS = 2
    RTK_FIXED = 4
    RTK_FLOAT = 5


class CommandFlag(enum.IntFlag):
    E_STOP = 0x01
    E_STOP_RELEASE = 0x02


COMMAND_FLAGS_DEFINED: Final = 0x03
NO_COMMAND_FLAGS: Final = CommandFlag(0)


class TelemetryStatus(enum.IntFlag):
    E_STOP_LATCHED = 0x01
    DEAD_MAN = 0x02
    TTL_EXPIRED = 0x04
    CLAMPED = 0x08
    LOW_BATTERY = 0x10
    GPS_STALE = 0x20
    WATCHDOG_RESET = 0x40
    LOCAL_STOP = 0x80


@dataclass(frozen=True, slots=True)
class CommandFrame:
    """BS → robot: what the robot should do for the next ``ttl_ms`` milliseconds."""

    seq: int
    velocity_mm_s: int
    direction: Direction
    flags: CommandFlag = NO_COMMAND_FLAGS
    ttl_ms: int = DEAD_MAN_MS
    to_node: int = ROBOT_NODE
    from_node: int = BASESTATION_NODE

    @property
    def velocity_mps(self) -> float:
        return self.velocity_mm_s / 1000.0


@dataclass(frozen=True, slots=True)
class TelemetryFrame:
    """Robot → BS: the answer to one command."""

    seq: int
    echo_seq: int
    robot_clock_ms: int
    velocity_mm_s: int
    direction: Direction
    battery_10mv: int
    lat_e7: int
    lon_e7: int
    fix_quality: FixQuality
    satellites: int
    status: TelemetryStatus
    rssi_dbm: int
    to_node: int = BASESTATION_NODE
    from_node: int = ROBOT_NODE

    @property
    def velocity_mps(self) -> float:
        return self.velocity_mm_s / 1000.0

    @property
    def battery_v(self) -> float:
        return self.battery_10mv / 100.0

    @property
    def lat_deg(self) -> float:
        return self.lat_e7 / 1e7

    @property
    def lon_deg(self) -> float:
        return self.lon_e7 / 1e7


@dataclass(frozen=True, slots=True)
class ConfigFrame:
    """Both ways: the BS asks for limits; the robot answers with the limits it applied."""

    seq: int
    max_velocity_mm_s: int
    accel_mm_s2: int
    to_node: int = ROBOT_NODE
    from_node: int = BASESTATION_NODE


@dataclass(frozen=True, slots=True)
class ConfigAckFrame:
    """Robot → BS: the limits the robot applied and the hard maximum compiled into it.

    ``hard_max_velocity_mm_s`` bounds every limit a config frame can set: the agent refuses
    to run with a configured limit above it (docs/protocol.md §2.4).
    """

    seq: int
    max_velocity_mm_s: int
    accel_mm_s2: int
    hard_max_velocity_mm_s: int
    to_node: int = BASESTATION_NODE
    from_node: int = ROBOT_NODE


@dataclass(frozen=True, slots=True)
class IdentifyFrame:
    """BS → robot: which firmware are you, built how? (docs/protocol.md §2.5)"""

    seq: int
    to_node: int = ROBOT_NODE
    from_node: int = BASESTATION_NODE


@dataclass(frozen=True, slots=True)
class IdentityFrame:
    """Robot → BS: the firmware's build identifier and its compiled-in configuration
    (docs/protocol.md §2.6). ``build_id`` is printable ASCII, at most 16 characters."""

    seq: int
    build_id: str
    hard_max_velocity_mm_s: int
    max_velocity_mm_s: int
    accel_mm_s2: int
    accel_min_mm_s2: int
    accel_max_mm_s2: int
    stop_decel_mm_s2: int
    dead_man_ms: int
    reverse_dwell_ms: int
    full_scale_mm_s: int
    low_battery_10mv: int
    gps_stale_ms: int
    battery_median_window: int
    to_node: int = BASESTATION_NODE
    from_node: int = ROBOT_NODE


#: The configuration fields of an identity frame, in wire order after the build identifier.
IDENTITY_CONFIG_FIELDS: Final = (
    "hard_max_velocity_mm_s",
    "max_velocity_mm_s",
    "accel_mm_s2",
    "accel_min_mm_s2",
    "accel_max_mm_s2",
    "stop_decel_mm_s2",
    "dead_man_ms",
    "reverse_dwell_ms",
    "full_scale_mm_s",
    "low_battery_10mv",
    "gps_stale_ms",
    "battery_median_window",
)

Frame = CommandFrame | TelemetryFrame | ConfigFrame | ConfigAckFrame | IdentifyFrame | IdentityFrame
