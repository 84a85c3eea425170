"""The Python wire codec against docs/protocol.md and the shared test vectors."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from basestation.protocol import (
    FRAME_ERROR_KINDS,
    CommandFlag,
    CommandFrame,
    ConfigAckFrame,
    ConfigFrame,
    Direction,
    FixQuality,
    Frame,
    FrameError,
    IdentifyFrame,
    IdentityFrame,
    TelemetryFrame,
    TelemetryStatus,
    decode_command,
    decode_config,
    decode_config_ack,
    decode_frame,
    decode_identity,
    decode_telemetry,
    encode_command,
    encode_config,
    encode_config_ack,
    encode_frame,
    encode_identity,
    encode_telemetry,
)

VECTORS_PATH = Path(__file__).resolve().parents[1] / "vectors" / "protocol.json"
VECTORS: dict[str, Any] = json.loads(VECTORS_PATH.read_text(encoding="utf-8"))
FRAME_CLASS: dict[str, type[Any]] = {
    "command": CommandFrame,
    "telemetry": TelemetryFrame,
    "config": ConfigFrame,
    "config_ack": ConfigAckFrame,
    "identify": IdentifyFrame,
    "identity": IdentityFrame,
}


def _expected_frame(vector: dict[str, Any]) -> Frame:
    return FRAME_CLASS[vector["type"]](**vector["fields"])


def _ids(vectors: list[dict[str, Any]]) -> list[str]:
    return [v["name"] for v in vectors]


def test_the_vector_file_covers_every_frame_type_and_error_kind() -> None:
    assert {v["type"] for v in VECTORS["valid"]} == set(FRAME_CLASS)
    assert {v["error"] for v in VECTORS["malformed"]} == FRAME_ERROR_KINDS
    assert set(VECTORS["error_kinds"]) == FRAME_ERROR_KINDS


@pytest.mark.parametrize("vector", VECTORS["valid"], ids=_ids(VECTORS["valid"]))
def test_it_decodes_each_valid_vector_to_its_fields(vector: dict[str, Any]) -> None:
    frame = decode_frame(bytes.fromhex(vector["hex"]))

    assert type(frame) is FRAME_CLASS[vector["type"]]
    assert frame == _expected_frame(vector)


@pytest.mark.parametrize("vector", VECTORS["valid"], ids=_ids(VECTORS["valid"]))
def test_it_encodes_each_valid_vector_to_its_bytes(vector: dict[str, Any]) -> None:
    assert encode_frame(_expected_frame(vector)).hex() == vector["hex"]


@pytest.mark.parametrize("vector", VECTORS["malformed"], ids=_ids(VECTORS["malformed"]))
def test_it_rejects_each_malformed_vector_with_its_kind(vector: dict[str, Any]) -> None:
    with pytest.raises(FrameError) as caught:
        decode_frame(bytes.fromhex(vector["hex"]))

    assert caught.value.kind == vector["error"]


def test_typed_decoders_reject_a_valid_frame_of_another_type() -> None:
    telemetry = next(v for v in VECTORS["valid"] if v["type"] == "telemetry")
    data = bytes.fromhex(telemetry["hex"])

    with pytest.raises(FrameError) as caught:
        decode_command(data)
    assert caught.value.kind == "unknown_type"
    with pytest.raises(FrameError):
        decode_config(data)
    with pytest.raises(FrameError):
        decode_config_ack(data)
    with pytest.raises(FrameError):
        decode_identity(data)
    assert decode_telemetry(data).seq == telemetry["fields"]["seq"]


def test_decoded_values_carry_enum_types_and_units() -> None:
    frame = decode_telemetry(
        bytes.fromhex(next(v["hex"] for v in VECTORS["valid"] if v["name"].startswith("telemetry")))
    )

    assert isinstance(frame.direction, Direction)
    assert isinstance(frame.fix_quality, FixQuality)
    assert isinstance(frame.status, TelemetryStatus)
    assert frame.battery_v == pytest.approx(frame.battery_10mv / 100)
    assert frame.lat_deg == pytest.approx(40.634172)


def test_it_refuses_to_encode_what_it_would_refuse_to_decode() -> None:
    with pytest.raises(FrameError) as caught:
        encode_command(CommandFrame(seq=1, velocity_mm_s=10_001, direction=Direction.CW))
    assert caught.value.kind == "out_of_range"
    with pytest.raises(FrameError) as caught:
        encode_command(
            CommandFrame(seq=1, velocity_mm_s=1, direction=Direction.CW, flags=CommandFlag(4))
        )
    assert caught.value.kind == "reserved_bits"
    with pytest.raises(FrameError) as caught:
        encode_config(ConfigFrame(seq=1, max_velocity_mm_s=100, accel_mm_s2=0))
    assert caught.value.kind == "out_of_range"
    with pytest.raises(FrameError) as caught:
        encode_config_ack(
            ConfigAckFrame(
                seq=1, max_velocity_mm_s=100, accel_mm_s2=1, hard_max_velocity_mm_s=10_001
            )
        )
    assert caught.value.kind == "out_of_range"
    with pytest.raises(FrameError) as caught:
        encode_command(CommandFrame(seq=65_536, velocity_mm_s=0, direction=Direction.CW))
    assert caught.value.kind == "out_of_range"


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"build_id": "x" * 17}, "over 16 characters"),
        ({"build_id": "v1\n"}, "not printable ASCII"),
        ({"build_id": "café"}, "not printable ASCII"),
        ({"hard_max_velocity_mm_s": 10_001}, "hard_max_velocity_mm_s"),
        ({"accel_min_mm_s2": 0}, "accel_mm_s2 0"),
        ({"battery_median_window": 256}, "battery_median_window"),
    ],
)
def test_an_identity_the_decoder_would_refuse_is_not_encoded(
    change: dict[str, Any], says: str
) -> None:
    vector = next(v for v in VECTORS["valid"] if v["type"] == "identity")
    fields = {**vector["fields"], **change}
    with pytest.raises(FrameError) as caught:
        encode_identity(IdentityFrame(**fields))
    assert caught.value.kind == "out_of_range"
    assert says in caught.value.message


# --- properties ---------------------------------------------------------------------------

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)

commands = st.builds(
    CommandFrame,
    seq=u16,
    velocity_mm_s=st.integers(0, 10_000),
    direction=st.sampled_from(Direction),
    flags=st.sampled_from([CommandFlag(v) for v in range(4)]),
    ttl_ms=u16,
    to_node=u8,
    from_node=u8,
)
telemetries = st.builds(
    TelemetryFrame,
    seq=u16,
    echo_seq=u16,
    robot_clock_ms=st.integers(0, 0xFFFF_FFFF),
    velocity_mm_s=u16,
    direction=st.sampled_from(Direction),
    battery_10mv=u16,
    lat_e7=st.integers(-900_000_000, 900_000_000),
    lon_e7=st.integers(-1_800_000_000, 1_800_000_000),
    fix_quality=st.sampled_from(FixQuality),
    satellites=u8,
    status=st.builds(TelemetryStatus, u8),
    rssi_dbm=st.integers(-128, 127),
    to_node=u8,
    from_node=u8,
)
configs = st.builds(
    ConfigFrame,
    seq=u16,
    max_velocity_mm_s=st.integers(0, 10_000),
    accel_mm_s2=st.integers(1, 10_000),
    to_node=u8,
    from_node=u8,
)
config_acks = st.builds(
    ConfigAckFrame,
    seq=u16,
    max_velocity_mm_s=st.integers(0, 10_000),
    accel_mm_s2=st.integers(1, 10_000),
    hard_max_velocity_mm_s=st.integers(0, 10_000),
    to_node=u8,
    from_node=u8,
)

identifies = st.builds(IdentifyFrame, seq=u16, to_node=u8, from_node=u8)
identities = st.builds(
    IdentityFrame,
    seq=u16,
    build_id=st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=16),
    hard_max_velocity_mm_s=st.integers(0, 10_000),
    max_velocity_mm_s=st.integers(0, 10_000),
    accel_mm_s2=st.integers(1, 10_000),
    accel_min_mm_s2=st.integers(1, 10_000),
    accel_max_mm_s2=st.integers(1, 10_000),
    stop_decel_mm_s2=u16,
    dead_man_ms=u16,
    reverse_dwell_ms=u16,
    full_scale_mm_s=u16,
    low_battery_10mv=u16,
    gps_stale_ms=u16,
    battery_median_window=u8,
    to_node=u8,
    from_node=u8,
)


@given(st.one_of(commands, telemetries, configs, config_acks, identifies, identities))
def test_every_valid_frame_survives_a_round_trip(frame: Frame) -> None:
    data = encode_frame(frame)

    assert data[0] == len(data) - 1
    assert decode_frame(data) == frame
    assert encode_frame(decode_frame(data)) == data


def _decode_or_error_kind(data: bytes) -> Frame | str:
    """The decoded frame, or the kind of the FrameError; any other exception escapes."""
    try:
        return decode_frame(data)
    except FrameError as error:
        return error.kind


@given(st.binary(max_size=80))
def test_arbitrary_bytes_decode_to_a_frame_or_a_frame_error(data: bytes) -> None:
    result = _decode_or_error_kind(data)

    if isinstance(result, str):
        assert result in FRAME_ERROR_KINDS
    else:
        assert encode_frame(result) == data


@given(st.sampled_from(VECTORS["valid"]), st.data())
def test_a_flipped_byte_in_a_valid_frame_never_escapes_as_another_exception(
    vector: dict[str, Any], data: st.DataObject
) -> None:
    raw = bytearray.fromhex(vector["hex"])
    index = data.draw(st.integers(0, len(raw) - 1))
    raw[index] = data.draw(u8)

    result = _decode_or_error_kind(bytes(raw))

    if isinstance(result, str):
        assert result in FRAME_ERROR_KINDS
    else:
        assert encode_frame(result) == bytes(raw)


@given(commands)
def test_command_encoders_are_typed(frame: CommandFrame) -> None:
    assert decode_command(encode_command(frame)) == frame


@given(telemetries)
def test_telemetry_encoders_are_typed(frame: TelemetryFrame) -> None:
    assert decode_telemetry(encode_telemetry(frame)) == frame
