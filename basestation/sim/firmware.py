"""The robot's firmware core, loaded from ``libamazing_robot.so`` through ctypes.

The structs mirror ``firmware/capi/amazing_robot.h`` (ABI version 3) field for field; the
library is built by ``make -C firmware shared`` (g++ only). Nothing here re-implements robot
logic: :class:`FirmwareRobot` is a thin, typed handle on the C API so that the simulator runs
the same control code as the Arduino.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import shutil
import subprocess
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Final

REPO_DIR: Final = Path(__file__).resolve().parents[2]
FIRMWARE_DIR: Final = REPO_DIR / "firmware"
DEFAULT_LIBRARY: Final = FIRMWARE_DIR / "host" / "build" / "libamazing_robot.so"
#: Overrides the library's path (an installed agent has no firmware tree to build from).
LIBRARY_ENV: Final = "AMZ_ROBOT_LIBRARY"
ABI_VERSION: Final = 3
#: The RFM69 FIFO: no frame, in or out, is longer.
MAX_FRAME_SIZE: Final = 66


class FirmwareError(Exception):
    """The firmware library is missing, cannot be built, or is not the ABI we speak."""


class AmzCommand(ctypes.Structure):
    _fields_ = [
        ("to_node", ctypes.c_uint8),
        ("from_node", ctypes.c_uint8),
        ("seq", ctypes.c_uint16),
        ("velocity_mm_s", ctypes.c_uint16),
        ("direction", ctypes.c_uint8),
        ("flags", ctypes.c_uint8),
        ("ttl_ms", ctypes.c_uint16),
    ]


class AmzTelemetry(ctypes.Structure):
    _fields_ = [
        ("to_node", ctypes.c_uint8),
        ("from_node", ctypes.c_uint8),
        ("seq", ctypes.c_uint16),
        ("echo_seq", ctypes.c_uint16),
        ("robot_clock_ms", ctypes.c_uint32),
        ("velocity_mm_s", ctypes.c_uint16),
        ("direction", ctypes.c_uint8),
        ("battery_10mv", ctypes.c_uint16),
        ("lat_e7", ctypes.c_int32),
        ("lon_e7", ctypes.c_int32),
        ("fix_quality", ctypes.c_uint8),
        ("satellites", ctypes.c_uint8),
        ("status", ctypes.c_uint8),
        ("rssi_dbm", ctypes.c_int8),
    ]


class AmzConfig(ctypes.Structure):
    _fields_ = [
        ("to_node", ctypes.c_uint8),
        ("from_node", ctypes.c_uint8),
        ("seq", ctypes.c_uint16),
        ("max_velocity_mm_s", ctypes.c_uint16),
        ("accel_mm_s2", ctypes.c_uint16),
    ]


class AmzConfigAck(ctypes.Structure):
    _fields_ = [
        ("to_node", ctypes.c_uint8),
        ("from_node", ctypes.c_uint8),
        ("seq", ctypes.c_uint16),
        ("max_velocity_mm_s", ctypes.c_uint16),
        ("accel_mm_s2", ctypes.c_uint16),
        ("hard_max_velocity_mm_s", ctypes.c_uint16),
    ]


class AmzIdentify(ctypes.Structure):
    _fields_ = [
        ("to_node", ctypes.c_uint8),
        ("from_node", ctypes.c_uint8),
        ("seq", ctypes.c_uint16),
    ]


class AmzIdentity(ctypes.Structure):
    _fields_ = [
        ("to_node", ctypes.c_uint8),
        ("from_node", ctypes.c_uint8),
        ("seq", ctypes.c_uint16),
        ("build_id", ctypes.c_char * 17),
        ("hard_max_velocity_mm_s", ctypes.c_uint16),
        ("max_velocity_mm_s", ctypes.c_uint16),
        ("accel_mm_s2", ctypes.c_uint16),
        ("accel_min_mm_s2", ctypes.c_uint16),
        ("accel_max_mm_s2", ctypes.c_uint16),
        ("stop_decel_mm_s2", ctypes.c_uint16),
        ("dead_man_ms", ctypes.c_uint16),
        ("reverse_dwell_ms", ctypes.c_uint16),
        ("full_scale_mm_s", ctypes.c_uint16),
        ("low_battery_10mv", ctypes.c_uint16),
        ("gps_stale_ms", ctypes.c_uint16),
        ("battery_median_window", ctypes.c_uint8),
    ]


class AmzFrame(ctypes.Structure):
    _fields_ = [
        ("type", ctypes.c_uint8),
        ("command", AmzCommand),
        ("telemetry", AmzTelemetry),
        ("config", AmzConfig),
        ("config_ack", AmzConfigAck),
        ("identify", AmzIdentify),
        ("identity", AmzIdentity),
    ]


class AmzMotionOutput(ctypes.Structure):
    _fields_ = [
        ("duty", ctypes.c_uint8),
        ("direction", ctypes.c_uint8),
        ("drive_enabled", ctypes.c_uint8),
        ("status", ctypes.c_uint8),
        ("velocity_mm_s", ctypes.c_int32),
    ]


class AmzRobotConfig(ctypes.Structure):
    _fields_ = [
        ("node", ctypes.c_uint8),
        ("base_node", ctypes.c_uint8),
        ("max_velocity_mm_s", ctypes.c_uint16),
        ("accel_mm_s2", ctypes.c_uint16),
        ("stop_decel_mm_s2", ctypes.c_uint16),
        ("dead_man_ms", ctypes.c_uint16),
        ("reverse_dwell_ms", ctypes.c_uint16),
        ("full_scale_mm_s", ctypes.c_uint16),
        ("duty_min", ctypes.c_uint8),
        ("duty_max", ctypes.c_uint8),
        ("hard_max_velocity_mm_s", ctypes.c_uint16),
        ("accel_min_mm_s2", ctypes.c_uint16),
        ("accel_max_mm_s2", ctypes.c_uint16),
        ("battery_vref_mv", ctypes.c_uint16),
        ("battery_divider_num", ctypes.c_uint16),
        ("battery_divider_den", ctypes.c_uint16),
        ("battery_adc_full_scale", ctypes.c_uint16),
        ("battery_median_window", ctypes.c_uint8),
        ("low_battery_10mv", ctypes.c_uint16),
        ("low_battery_hysteresis_10mv", ctypes.c_uint16),
        ("gps_stale_ms", ctypes.c_uint16),
        ("wheel_stale_ms", ctypes.c_uint16),
        # NUL-terminated, at most 16 printable ASCII characters (AMZ_BUILD_ID).
        ("build_id", ctypes.c_char * 17),
    ]


_P = ctypes.c_void_p
_U8 = ctypes.c_uint8
_U16 = ctypes.c_uint16
_U32 = ctypes.c_uint32
_SIZE = ctypes.c_size_t
_INT = ctypes.c_int

# name: (restype, argtypes), from amazing_robot.h.
_PROTOTYPES: Final[dict[str, tuple[object, list[object]]]] = {
    "amz_abi_version": (_U32, []),
    "amz_robot_default_config": (None, [_P]),
    "amz_robot_create": (_P, [_P, _U32, _INT, _INT]),
    "amz_robot_destroy": (None, [_P]),
    "amz_robot_handle_frame": (_SIZE, [_P, _U32, ctypes.c_char_p, _SIZE, ctypes.c_int8, _P, _SIZE]),
    "amz_robot_step": (None, [_P, _U32, _P]),
    "amz_robot_add_battery_sample": (None, [_P, _U16]),
    "amz_robot_feed_gps": (None, [_P, _U32, ctypes.c_char_p, _SIZE]),
    "amz_robot_set_local_stop": (None, [_P, _INT]),
    "amz_robot_set_measured_velocity": (None, [_P, _U32, _U16]),
    "amz_robot_e_stop_latched": (_INT, [_P]),
    "amz_robot_status": (_U8, [_P, _U32]),
    "amz_robot_battery_10mv": (_U16, [_P]),
    "amz_decode_frame": (_INT, [ctypes.c_char_p, _SIZE, _P]),
    "amz_frame_error_name": (ctypes.c_char_p, [_INT]),
    "amz_parse_gga": (_INT, [ctypes.c_char_p, _SIZE, _P]),
}

_lock = threading.Lock()
_loaded: dict[Path, ctypes.CDLL] = {}


def build_library() -> Path:
    """Run ``make -s -C firmware shared`` and return the library's path.

    ``make`` rebuilds only what changed, so calling this on every start costs milliseconds and
    never runs a simulator against firmware older than its source.
    """
    if shutil.which("make") is None or shutil.which("g++") is None:
        raise FirmwareError("make and g++ are needed to build libamazing_robot.so")
    # One build at a time on this tree: agents started together (two robots, several
    # systems at once) would otherwise write the same objects at the same time.
    DEFAULT_LIBRARY.parent.mkdir(parents=True, exist_ok=True)
    with (DEFAULT_LIBRARY.parent / ".build.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        result = subprocess.run(  # noqa: S603 - fixed argv, no shell
            ["make", "-s", "-C", str(FIRMWARE_DIR), "shared"],  # noqa: S607 - make from PATH
            capture_output=True,
            text=True,
            check=False,
        )
    if result.returncode != 0:
        raise FirmwareError(f"make -C firmware shared failed:\n{result.stdout}{result.stderr}")
    return DEFAULT_LIBRARY


def load_library(path: Path | str | None = None, *, build: bool = True) -> ctypes.CDLL:
    """The firmware library with every prototype declared (loaded once per path).

    ``path`` defaults to ``$AMZ_ROBOT_LIBRARY`` or the firmware tree's build output; with
    ``build`` the library is (re)built by ``make`` first when the firmware tree is present.
    """
    if path is None:
        env = os.environ.get(LIBRARY_ENV)
        if env:
            path = Path(env)
        else:
            with _lock:
                cached = _loaded.get(DEFAULT_LIBRARY.resolve())
            if cached is not None:  # built and loaded once per process
                return cached
            if build and (FIRMWARE_DIR / "Makefile").is_file():
                path = build_library()
            else:
                path = DEFAULT_LIBRARY
    resolved = Path(path).resolve()
    with _lock:
        if resolved in _loaded:
            return _loaded[resolved]
        if not resolved.is_file():
            raise FirmwareError(
                f"{resolved} does not exist: run `make -C firmware shared` or set {LIBRARY_ENV}"
            )
        library = ctypes.CDLL(str(resolved))
        for name, (restype, argtypes) in _PROTOTYPES.items():
            function = getattr(library, name)
            function.restype = restype
            function.argtypes = argtypes
        version = int(library.amz_abi_version())
        if version != ABI_VERSION:
            raise FirmwareError(f"{resolved} has ABI version {version}, expected {ABI_VERSION}")
        _loaded[resolved] = library
        return library


def default_robot_config(library: ctypes.CDLL | None = None) -> AmzRobotConfig:
    """The firmware's compiled-in configuration (``core/robot_config.h``)."""
    config = AmzRobotConfig()
    (library or load_library()).amz_robot_default_config(ctypes.byref(config))
    return config


@dataclass(frozen=True, slots=True)
class MotionOutput:
    """What the firmware drives the motor with after one step."""

    duty: int  # 0..255 PWM
    direction: int  # 0 = CCW, 1 = CW (the direction pin)
    drive_enabled: bool  # False while the e-stop is latched (driver enable LOW)
    status: int  # telemetry status flags at this step
    velocity_mm_s: int  # the controller's applied (ramped) speed, signed, + = CW


class FirmwareRobot:
    """One ``amz_robot`` instance: the robot's control code, fed with times in ms."""

    def __init__(
        self,
        library: ctypes.CDLL | None = None,
        *,
        config: AmzRobotConfig | None = None,
        now_ms: int = 0,
        e_stop_latched: bool = False,
        watchdog_reset: bool = False,
    ) -> None:
        self._lib = library if library is not None else load_library()
        self.config = config if config is not None else default_robot_config(self._lib)
        handle = self._lib.amz_robot_create(
            ctypes.byref(self.config), now_ms & 0xFFFFFFFF, int(e_stop_latched), int(watchdog_reset)
        )
        if not handle:
            raise FirmwareError("amz_robot_create returned NULL")
        self._handle: int | None = handle
        # Reused on every call: a simulation steps a thousand times per simulated second.
        self._out = AmzMotionOutput()
        self._out_ref = ctypes.byref(self._out)
        self._reply = (ctypes.c_uint8 * MAX_FRAME_SIZE)()

    @property
    def handle(self) -> int:
        if self._handle is None:
            raise FirmwareError("the firmware robot was closed")
        return self._handle

    def close(self) -> None:
        if self._handle is not None:
            self._lib.amz_robot_destroy(self._handle)
            self._handle = None

    def __del__(self) -> None:  # a forgotten close() must not leak the C object
        # At interpreter shutdown there is nobody left to report a failure to.
        with contextlib.suppress(Exception):
            self.close()

    def handle_frame(self, now_ms: int, frame: bytes, rssi_dbm: int) -> bytes:
        """A frame as read from the radio FIFO; returns the reply to transmit (may be empty)."""
        rssi = max(-128, min(127, int(rssi_dbm)))
        n = self._lib.amz_robot_handle_frame(
            self.handle, now_ms & 0xFFFFFFFF, bytes(frame), len(frame), rssi,
            self._reply, MAX_FRAME_SIZE,
        )  # fmt: skip
        return bytes(self._reply[:n])

    def step(self, now_ms: int) -> MotionOutput:
        self._lib.amz_robot_step(self.handle, now_ms & 0xFFFFFFFF, self._out_ref)
        out = self._out
        return MotionOutput(
            duty=out.duty,
            direction=out.direction,
            drive_enabled=bool(out.drive_enabled),
            status=out.status,
            velocity_mm_s=out.velocity_mm_s,
        )

    def add_battery_sample(self, adc_counts: int) -> None:
        self._lib.amz_robot_add_battery_sample(self.handle, max(0, min(0xFFFF, adc_counts)))

    def feed_gps(self, now_ms: int, data: bytes) -> None:
        self._lib.amz_robot_feed_gps(self.handle, now_ms & 0xFFFFFFFF, data, len(data))

    def set_local_stop(self, open_: bool) -> None:
        self._lib.amz_robot_set_local_stop(self.handle, int(open_))

    def set_measured_velocity(self, now_ms: int, velocity_mm_s: int) -> None:
        self._lib.amz_robot_set_measured_velocity(
            self.handle, now_ms & 0xFFFFFFFF, max(0, min(0xFFFF, velocity_mm_s))
        )

    @property
    def e_stop_latched(self) -> bool:
        return bool(self._lib.amz_robot_e_stop_latched(self.handle))

    def status(self, now_ms: int) -> int:
        return int(self._lib.amz_robot_status(self.handle, now_ms & 0xFFFFFFFF))

    @property
    def battery_10mv(self) -> int:
        return int(self._lib.amz_robot_battery_10mv(self.handle))
