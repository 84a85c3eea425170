"""Encode and decode wire-protocol frames (docs/protocol.md), checks in the documented order."""

from __future__ import annotations

import struct
from typing import Final

from basestation.protocol.errors import FrameError
from basestation.protocol.frames import (
    ACCEL_LIMIT_MM_S2,
    BUILD_ID_SIZE,
    COMMAND_FLAGS_DEFINED,
    COMMAND_FRAME_SIZE,
    CONFIG_ACK_FRAME_SIZE,
    CONFIG_FRAME_SIZE,
    HEADER_SIZE,
    IDENTIFY_FRAME_SIZE,
    IDENTITY_CONFIG_FIELDS,
    IDENTITY_FRAME_SIZE,
    LAT_LIMIT_E7,
    LON_LIMIT_E7,
    PROTOCOL_VERSION,
    TELEMETRY_FRAME_SIZE,
    VELOCITY_LIMIT_MM_S,
    CommandFlag,
    CommandFrame,
    ConfigAckFrame,
    ConfigFrame,
    Direction,
    FixQuality,
    Frame,
    FrameType,
    IdentifyFrame,
    IdentityFrame,
    TelemetryFrame,
    TelemetryStatus,
)

Buffer = bytes | bytearray | memoryview

_HEADER: Final = struct.Struct("<BBBBBB")  # len, to, from, ctl, version, type
_COMMAND: Final = struct.Struct("<HHBBH")  # seq, velocity, direction, flags, ttl
_TELEMETRY: Final = struct.Struct("<HHIHBHiiBBBb")
_CONFIG: Final = struct.Struct("<HHH")  # seq, max velocity, acceleration
_CONFIG_ACK: Final = struct.Struct("<HHHH")  # seq, max velocity, acceleration, hard max velocity
_IDENTIFY: Final = struct.Struct("<H")  # seq
# seq, build id, then IDENTITY_CONFIG_FIELDS: eleven u16 and the median window (u8)
_IDENTITY: Final = struct.Struct(f"<H{BUILD_ID_SIZE}s11HB")

_FRAME_SIZE: Final[dict[int, int]] = {
    FrameType.COMMAND: COMMAND_FRAME_SIZE,
    FrameType.TELEMETRY: TELEMETRY_FRAME_SIZE,
    FrameType.CONFIG: CONFIG_FRAME_SIZE,
    FrameType.CONFIG_ACK: CONFIG_ACK_FRAME_SIZE,
    FrameType.IDENTIFY: IDENTIFY_FRAME_SIZE,
    FrameType.IDENTITY: IDENTITY_FRAME_SIZE,
}
_DIRECTIONS: Final = frozenset(int(d) for d in Direction)
_FIX_QUALITIES: Final = frozenset(int(q) for q in FixQuality)

assert HEADER_SIZE + _COMMAND.size == COMMAND_FRAME_SIZE
assert HEADER_SIZE + _TELEMETRY.size == TELEMETRY_FRAME_SIZE
assert HEADER_SIZE + _CONFIG.size == CONFIG_FRAME_SIZE
assert HEADER_SIZE + _CONFIG_ACK.size == CONFIG_ACK_FRAME_SIZE
assert HEADER_SIZE + _IDENTIFY.size == IDENTIFY_FRAME_SIZE
assert HEADER_SIZE + _IDENTITY.size == IDENTITY_FRAME_SIZE


# --- field checks shared by encoder and decoder ---------------------------------------------


def _check_velocity(velocity_mm_s: int, name: str = "velocity_mm_s") -> None:
    if not 0 <= velocity_mm_s <= VELOCITY_LIMIT_MM_S:
        raise FrameError("out_of_range", f"{name} {velocity_mm_s} not in 0..{VELOCITY_LIMIT_MM_S}")


def _check_direction(direction: int) -> None:
    if direction not in _DIRECTIONS:
        raise FrameError("bad_enum", f"direction {direction} is neither 0 (CCW) nor 1 (CW)")


def _check_command_flags(flags: int) -> None:
    if flags & ~COMMAND_FLAGS_DEFINED:
        raise FrameError("reserved_bits", f"command flags 0x{flags:02x} set reserved bits")


def _check_lat_lon(lat_e7: int, lon_e7: int) -> None:
    if not -LAT_LIMIT_E7 <= lat_e7 <= LAT_LIMIT_E7:
        raise FrameError("out_of_range", f"lat_e7 {lat_e7} outside ±90°")
    if not -LON_LIMIT_E7 <= lon_e7 <= LON_LIMIT_E7:
        raise FrameError("out_of_range", f"lon_e7 {lon_e7} outside ±180°")


def _check_fix_quality(fix_quality: int) -> None:
    if fix_quality not in _FIX_QUALITIES:
        raise FrameError("bad_enum", f"fix_quality {fix_quality} not one of 0, 1, 2, 4, 5")


def _check_accel(accel_mm_s2: int) -> None:
    if not 1 <= accel_mm_s2 <= ACCEL_LIMIT_MM_S2:
        raise FrameError("out_of_range", f"accel_mm_s2 {accel_mm_s2} not in 1..{ACCEL_LIMIT_MM_S2}")


def _check_wire_build_id(raw: bytes) -> str:
    """The identifier in its 16 bytes: printable ASCII up to the first NUL, only NULs after
    it (one spelling per identifier, so a decoded frame encodes back to the same bytes)."""
    text, _, padding = raw.partition(b"\0")
    if padding.strip(b"\0") or not all(0x20 <= b <= 0x7E for b in text):
        raise FrameError("out_of_range", f"build_id {raw!r} is not printable ASCII, NUL-padded")
    return text.decode("ascii")


def _check_build_id(build_id: str) -> bytes:
    if not isinstance(build_id, str) or not all(" " <= c <= "~" for c in build_id):
        raise FrameError("out_of_range", f"build_id {build_id!r} is not printable ASCII")
    if len(build_id) > BUILD_ID_SIZE:
        raise FrameError(
            "out_of_range", f"build_id {build_id!r} is over {BUILD_ID_SIZE} characters"
        )
    return build_id.encode("ascii")


def _check_identity_numbers(frame: IdentityFrame) -> None:
    _check_velocity(frame.hard_max_velocity_mm_s, "hard_max_velocity_mm_s")
    _check_velocity(frame.max_velocity_mm_s, "max_velocity_mm_s")
    _check_accel(frame.accel_mm_s2)
    _check_accel(frame.accel_min_mm_s2)
    _check_accel(frame.accel_max_mm_s2)


def _check_width(name: str, value: int, low: int, high: int) -> None:
    if not low <= value <= high:
        raise FrameError("out_of_range", f"{name} {value} does not fit in {low}..{high}")


def _check_u8(name: str, value: int) -> None:
    _check_width(name, value, 0, 0xFF)


def _check_u16(name: str, value: int) -> None:
    _check_width(name, value, 0, 0xFFFF)


def _header(frame_type: FrameType, size: int, to_node: int, from_node: int) -> bytes:
    _check_u8("to_node", to_node)
    _check_u8("from_node", from_node)
    return _HEADER.pack(size - 1, to_node, from_node, 0, PROTOCOL_VERSION, frame_type)


# --- encoders ------------------------------------------------------------------------------


def encode_command(frame: CommandFrame) -> bytes:
    _check_u16("seq", frame.seq)
    _check_velocity(frame.velocity_mm_s)
    _check_direction(frame.direction)
    _check_u8("flags", frame.flags)
    _check_command_flags(frame.flags)
    _check_u16("ttl_ms", frame.ttl_ms)
    header = _header(FrameType.COMMAND, COMMAND_FRAME_SIZE, frame.to_node, frame.from_node)
    body = _COMMAND.pack(frame.seq, frame.velocity_mm_s, frame.direction, frame.flags, frame.ttl_ms)
    return header + body


def encode_telemetry(frame: TelemetryFrame) -> bytes:
    _check_u16("seq", frame.seq)
    _check_u16("echo_seq", frame.echo_seq)
    _check_width("robot_clock_ms", frame.robot_clock_ms, 0, 0xFFFF_FFFF)
    _check_u16("velocity_mm_s", frame.velocity_mm_s)
    _check_direction(frame.direction)
    _check_u16("battery_10mv", frame.battery_10mv)
    _check_lat_lon(frame.lat_e7, frame.lon_e7)
    _check_fix_quality(frame.fix_quality)
    _check_u8("satellites", frame.satellites)
    _check_u8("status", frame.status)
    _check_width("rssi_dbm", frame.rssi_dbm, -128, 127)
    header = _header(FrameType.TELEMETRY, TELEMETRY_FRAME_SIZE, frame.to_node, frame.from_node)
    body = _TELEMETRY.pack(
        frame.seq,
        frame.echo_seq,
        frame.robot_clock_ms,
        frame.velocity_mm_s,
        frame.direction,
        frame.battery_10mv,
        frame.lat_e7,
        frame.lon_e7,
        frame.fix_quality,
        frame.satellites,
        frame.status,
        frame.rssi_dbm,
    )
    return header + body


def encode_config(frame: ConfigFrame) -> bytes:
    _check_u16("seq", frame.seq)
    _check_velocity(frame.max_velocity_mm_s, "max_velocity_mm_s")
    _check_accel(frame.accel_mm_s2)
    header = _header(FrameType.CONFIG, CONFIG_FRAME_SIZE, frame.to_node, frame.from_node)
    return header + _CONFIG.pack(frame.seq, frame.max_velocity_mm_s, frame.accel_mm_s2)


def encode_config_ack(frame: ConfigAckFrame) -> bytes:
    _check_u16("seq", frame.seq)
    _check_velocity(frame.max_velocity_mm_s, "max_velocity_mm_s")
    _check_accel(frame.accel_mm_s2)
    _check_velocity(frame.hard_max_velocity_mm_s, "hard_max_velocity_mm_s")
    header = _header(FrameType.CONFIG_ACK, CONFIG_ACK_FRAME_SIZE, frame.to_node, frame.from_node)
    body = _CONFIG_ACK.pack(
        frame.seq, frame.max_velocity_mm_s, frame.accel_mm_s2, frame.hard_max_velocity_mm_s
    )
    return header + body


def encode_identify(frame: IdentifyFrame) -> bytes:
    _check_u16("seq", frame.seq)
    header = _header(FrameType.IDENTIFY, IDENTIFY_FRAME_SIZE, frame.to_node, frame.from_node)
    return header + _IDENTIFY.pack(frame.seq)


def encode_identity(frame: IdentityFrame) -> bytes:
    _check_u16("seq", frame.seq)
    build_id = _check_build_id(frame.build_id)
    _check_identity_numbers(frame)
    numbers = [getattr(frame, name) for name in IDENTITY_CONFIG_FIELDS]
    for name, value in zip(IDENTITY_CONFIG_FIELDS[:-1], numbers[:-1], strict=True):
        _check_u16(name, value)
    _check_u8("battery_median_window", frame.battery_median_window)
    header = _header(FrameType.IDENTITY, IDENTITY_FRAME_SIZE, frame.to_node, frame.from_node)
    return header + _IDENTITY.pack(frame.seq, build_id, *numbers)


def encode_frame(frame: Frame) -> bytes:
    if isinstance(frame, IdentifyFrame):
        return encode_identify(frame)
    if isinstance(frame, IdentityFrame):
        return encode_identity(frame)
    if isinstance(frame, CommandFrame):
        return encode_command(frame)
    if isinstance(frame, TelemetryFrame):
        return encode_telemetry(frame)
    if isinstance(frame, ConfigAckFrame):
        return encode_config_ack(frame)
    return encode_config(frame)


# --- decoders ------------------------------------------------------------------------------


def _decode_header(data: Buffer) -> tuple[FrameType, int, int]:
    """Check the common header (§3 steps 1 to 6); return the type, ``to`` and ``from``."""
    raw = bytes(data)
    if len(raw) < HEADER_SIZE:
        raise FrameError("too_short", f"{len(raw)} bytes, the header alone is {HEADER_SIZE}")
    length, to_node, from_node, ctl, version, frame_type = _HEADER.unpack_from(raw)
    if length != len(raw) - 1:
        raise FrameError("length_mismatch", f"len byte {length}, {len(raw) - 1} bytes follow it")
    if ctl != 0:
        raise FrameError("reserved_bits", f"ctl byte 0x{ctl:02x} is not 0")
    if version != PROTOCOL_VERSION:
        raise FrameError("unknown_version", f"version {version}, expected {PROTOCOL_VERSION}")
    if frame_type not in _FRAME_SIZE:
        raise FrameError("unknown_type", f"frame type {frame_type}")
    expected = _FRAME_SIZE[frame_type]
    if len(raw) != expected:
        raise FrameError(
            "size_mismatch",
            f"{FrameType(frame_type).name.lower()} frame is {expected} bytes, got {len(raw)}",
        )
    return FrameType(frame_type), to_node, from_node


def _decode_command_body(raw: bytes, to_node: int, from_node: int) -> CommandFrame:
    seq, velocity_mm_s, direction, flags, ttl_ms = _COMMAND.unpack_from(raw, HEADER_SIZE)
    _check_velocity(velocity_mm_s)
    _check_direction(direction)
    _check_command_flags(flags)
    return CommandFrame(
        seq=seq,
        velocity_mm_s=velocity_mm_s,
        direction=Direction(direction),
        flags=CommandFlag(flags),
        ttl_ms=ttl_ms,
        to_node=to_node,
        from_node=from_node,
    )


def _decode_telemetry_body(raw: bytes, to_node: int, from_node: int) -> TelemetryFrame:
    (
        seq,
        echo_seq,
        robot_clock_ms,
        velocity_mm_s,
        direction,
        battery_10mv,
        lat_e7,
        lon_e7,
        fix_quality,
        satellites,
        status,
        rssi_dbm,
    ) = _TELEMETRY.unpack_from(raw, HEADER_SIZE)
    _check_direction(direction)
    _check_lat_lon(lat_e7, lon_e7)
    _check_fix_quality(fix_quality)
    return TelemetryFrame(
        seq=seq,
        echo_seq=echo_seq,
        robot_clock_ms=robot_clock_ms,
        velocity_mm_s=velocity_mm_s,
        direction=Direction(direction),
        battery_10mv=battery_10mv,
        lat_e7=lat_e7,
        lon_e7=lon_e7,
        fix_quality=FixQuality(fix_quality),
        satellites=satellites,
        status=TelemetryStatus(status),
        rssi_dbm=rssi_dbm,
        to_node=to_node,
        from_node=from_node,
    )


def _decode_config_body(raw: bytes, to_node: int, from_node: int) -> ConfigFrame:
    seq, max_velocity_mm_s, accel_mm_s2 = _CONFIG.unpack_from(raw, HEADER_SIZE)
    _check_velocity(max_velocity_mm_s, "max_velocity_mm_s")
    _check_accel(accel_mm_s2)
    return ConfigFrame(
        seq=seq,
        max_velocity_mm_s=max_velocity_mm_s,
        accel_mm_s2=accel_mm_s2,
        to_node=to_node,
        from_node=from_node,
    )


def _decode_config_ack_body(raw: bytes, to_node: int, from_node: int) -> ConfigAckFrame:
    seq, max_velocity_mm_s, accel_mm_s2, hard_max_mm_s = _CONFIG_ACK.unpack_from(raw, HEADER_SIZE)
    _check_velocity(max_velocity_mm_s, "max_velocity_mm_s")
    _check_accel(accel_mm_s2)
    _check_velocity(hard_max_mm_s, "hard_max_velocity_mm_s")
    return ConfigAckFrame(
        seq=seq,
        max_velocity_mm_s=max_velocity_mm_s,
        accel_mm_s2=accel_mm_s2,
        hard_max_velocity_mm_s=hard_max_mm_s,
        to_node=to_node,
        from_node=from_node,
    )


def _decode_identity_body(raw: bytes, to_node: int, from_node: int) -> IdentityFrame:
    seq, wire_id, *numbers = _IDENTITY.unpack_from(raw, HEADER_SIZE)
    build_id = _check_wire_build_id(wire_id)
    config = dict(zip(IDENTITY_CONFIG_FIELDS, numbers, strict=True))
    frame = IdentityFrame(
        seq=seq, build_id=build_id, to_node=to_node, from_node=from_node, **config
    )
    _check_identity_numbers(frame)
    return frame


def decode_frame(data: Buffer) -> Frame:
    """Decode any version-1 frame; raise :class:`FrameError` for anything else."""
    raw = bytes(data)
    frame_type, to_node, from_node = _decode_header(raw)
    if frame_type is FrameType.COMMAND:
        return _decode_command_body(raw, to_node, from_node)
    if frame_type is FrameType.TELEMETRY:
        return _decode_telemetry_body(raw, to_node, from_node)
    if frame_type is FrameType.CONFIG_ACK:
        return _decode_config_ack_body(raw, to_node, from_node)
    if frame_type is FrameType.IDENTIFY:
        (seq,) = _IDENTIFY.unpack_from(raw, HEADER_SIZE)
        return IdentifyFrame(seq=seq, to_node=to_node, from_node=from_node)
    if frame_type is FrameType.IDENTITY:
        return _decode_identity_body(raw, to_node, from_node)
    return _decode_config_body(raw, to_node, from_node)


def decode_command(data: Buffer) -> CommandFrame:
    """Decode a command frame; a valid frame of another type is rejected as ``unknown_type``."""
    frame = decode_frame(data)
    if not isinstance(frame, CommandFrame):
        raise FrameError("unknown_type", "expected a command frame")
    return frame


def decode_telemetry(data: Buffer) -> TelemetryFrame:
    """Decode a telemetry frame; a valid frame of another type is rejected as ``unknown_type``."""
    frame = decode_frame(data)
    if not isinstance(frame, TelemetryFrame):
        raise FrameError("unknown_type", "expected a telemetry frame")
    return frame


def decode_config_ack(data: Buffer) -> ConfigAckFrame:
    """Decode a config acknowledgement; a valid frame of another type is ``unknown_type``."""
    frame = decode_frame(data)
    if not isinstance(frame, ConfigAckFrame):
        raise FrameError("unknown_type", "expected a config acknowledgement")
    return frame


def decode_identity(data: Buffer) -> IdentityFrame:
    """Decode an identity frame; a valid frame of another type is rejected as ``unknown_type``."""
    frame = decode_frame(data)
    if not isinstance(frame, IdentityFrame):
        raise FrameError("unknown_type", "expected an identity frame")
    return frame


def decode_config(data: Buffer) -> ConfigFrame:
    """Decode a config frame; a valid frame of another type is rejected as ``unknown_type``."""
    frame = decode_frame(data)
    if not isinstance(frame, ConfigFrame):
        raise FrameError("unknown_type", "expected a config frame")
    return frame
