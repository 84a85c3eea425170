"""The Python codec and the firmware's C++ codec agree, through libamazing_robot.so.

Builds the library with ``make -C firmware shared`` (g++ only, no AVR toolchain needed).
"""

from __future__ import annotations

import ctypes
import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from basestation.protocol import (
    CommandFlag,
    CommandFrame,
    Direction,
    Frame,
    FrameError,
    TelemetryFrame,
    TelemetryStatus,
    decode_frame,
    decode_telemetry,
    encode_command,
    encode_frame,
)
from basestation.sim.firmware import AmzFrame as AnyFrame
from basestation.sim.firmware import AmzMotionOutput as MotionOutput
from basestation.sim.firmware import AmzRobotConfig as RobotConfig

REPO = Path(__file__).resolve().parents[2]
LIBRARY = REPO / "firmware" / "host" / "build" / "libamazing_robot.so"
VECTORS: dict[str, Any] = json.loads(
    (REPO / "tests" / "vectors" / "protocol.json").read_text(encoding="utf-8")
)


MEMBER = {
    1: "command",
    2: "telemetry",
    3: "config",
    4: "config_ack",
    5: "identify",
    6: "identity",
}


def _plain(value: Any) -> int | str:
    """A field as the vectors write it: text (the build id) as str, anything else as int."""
    if isinstance(value, bytes):
        return value.decode("ascii")
    return value if isinstance(value, str) else int(value)


@pytest.fixture(scope="module")
def lib() -> ctypes.CDLL:
    # Never skipped: a missing compiler is a broken test machine, not a passing test.
    assert shutil.which("make"), "make builds libamazing_robot.so"
    assert shutil.which("g++"), "g++ builds libamazing_robot.so"
    subprocess.run(
        ["make", "-s", "-C", str(REPO / "firmware"), "shared"], check=True, capture_output=True
    )
    library = ctypes.CDLL(str(LIBRARY))
    library.amz_decode_frame.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_void_p]
    library.amz_decode_frame.restype = ctypes.c_int
    library.amz_frame_error_name.argtypes = [ctypes.c_int]
    library.amz_frame_error_name.restype = ctypes.c_char_p
    library.amz_robot_create.argtypes = [
        ctypes.c_void_p,
        ctypes.c_uint32,
        ctypes.c_int,
        ctypes.c_int,
    ]
    library.amz_robot_create.restype = ctypes.c_void_p
    library.amz_robot_destroy.argtypes = [ctypes.c_void_p]
    library.amz_robot_handle_frame.argtypes = [
        ctypes.c_void_p,
        ctypes.c_uint32,
        ctypes.c_char_p,
        ctypes.c_size_t,
        ctypes.c_int8,
        ctypes.c_void_p,
        ctypes.c_size_t,
    ]
    library.amz_robot_handle_frame.restype = ctypes.c_size_t
    library.amz_robot_step.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_void_p]
    return library


def _c_decode(lib: ctypes.CDLL, data: bytes) -> dict[str, int | str] | str:
    """The C++ decoder's answer: the frame's fields, or its error kind."""
    out = AnyFrame()
    kind = lib.amz_decode_frame(data, len(data), ctypes.byref(out))
    if kind != 0:
        return str(lib.amz_frame_error_name(kind).decode())
    member = getattr(out, MEMBER[out.type])
    return {name: _plain(getattr(member, name)) for name, _ in member._fields_}


def _py_decode(data: bytes) -> dict[str, int | str] | str:
    try:
        frame = decode_frame(data)
    except FrameError as error:
        return error.kind
    return {name: _plain(getattr(frame, name)) for name in frame.__dataclass_fields__}


@pytest.mark.parametrize("vector", VECTORS["valid"], ids=[v["name"] for v in VECTORS["valid"]])
def test_firmware_decodes_each_valid_vector_to_its_fields(
    lib: ctypes.CDLL, vector: dict[str, Any]
) -> None:
    assert _c_decode(lib, bytes.fromhex(vector["hex"])) == vector["fields"]


@pytest.mark.parametrize(
    "vector", VECTORS["malformed"], ids=[v["name"] for v in VECTORS["malformed"]]
)
def test_firmware_rejects_each_malformed_vector_with_its_kind(
    lib: ctypes.CDLL, vector: dict[str, Any]
) -> None:
    assert _c_decode(lib, bytes.fromhex(vector["hex"])) == vector["error"]


@settings(max_examples=500)
@given(data=st.binary(max_size=40) | st.sampled_from(VECTORS["valid"]).map(lambda v: v["hex"]))
def test_python_and_firmware_decoders_agree_on_any_bytes(
    lib: ctypes.CDLL, data: bytes | str
) -> None:
    raw = bytes.fromhex(data) if isinstance(data, str) else data
    assert _c_decode(lib, raw) == _py_decode(raw)


@settings(max_examples=300)
@given(
    header=st.sampled_from(
        [
            bytes([13, 2, 1, 0, 1, 1]),
            bytes([30, 1, 2, 0, 1, 2]),
            bytes([11, 2, 1, 0, 1, 3]),
            bytes([13, 1, 2, 0, 1, 4]),
            bytes([7, 2, 1, 0, 1, 5]),
            bytes([46, 1, 2, 0, 1, 6]),
        ]
    ),
    body=st.binary(min_size=41, max_size=41),
)
def test_decoders_agree_on_well_framed_random_payloads(
    lib: ctypes.CDLL, header: bytes, body: bytes
) -> None:
    raw = header + body[: header[0] - 5]
    assert _c_decode(lib, raw) == _py_decode(raw)


def test_simulated_robot_answers_a_python_command(lib: ctypes.CDLL) -> None:
    robot = lib.amz_robot_create(None, 0, 0, 0)
    assert robot is None  # a config is required
    config = RobotConfig()
    lib.amz_robot_default_config(ctypes.byref(config))
    assert (config.node, config.base_node, config.dead_man_ms) == (2, 1, 500)
    robot = lib.amz_robot_create(ctypes.byref(config), 0, 0, 0)
    try:
        reply = (ctypes.c_uint8 * 66)()
        frame: Frame | None = None
        for tick in range(1, 21):
            command = encode_command(
                CommandFrame(seq=tick, velocity_mm_s=1000, direction=Direction.CCW, ttl_ms=500)
            )
            now_ms = tick * 50
            lib.amz_robot_step(robot, now_ms, None)
            n = lib.amz_robot_handle_frame(robot, now_ms, command, len(command), -64, reply, 66)
            frame = decode_telemetry(bytes(reply[:n]))
        assert isinstance(frame, TelemetryFrame)
        assert frame.echo_seq == 20
        assert frame.seq == 19
        assert frame.rssi_dbm == -64
        assert frame.direction is Direction.CCW
        assert 0 < frame.velocity_mm_s <= 250
        assert TelemetryStatus.DEAD_MAN not in frame.status

        stop = encode_frame(
            CommandFrame(seq=21, velocity_mm_s=0, direction=Direction.CCW, flags=CommandFlag.E_STOP)
        )
        n = lib.amz_robot_handle_frame(robot, 1050, stop, len(stop), -64, reply, 66)
        output = MotionOutput()
        lib.amz_robot_step(robot, 1051, ctypes.byref(output))
        assert output.duty == 0
        assert output.drive_enabled == 0
        assert TelemetryStatus.E_STOP_LATCHED in decode_telemetry(bytes(reply[:n])).status
    finally:
        lib.amz_robot_destroy(robot)
