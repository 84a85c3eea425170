"""The flashed image as the simulated robot's firmware: ``robot.elf`` on the emulated board.

:class:`FlashedRobot` has :class:`~basestation.sim.firmware.FirmwareRobot`'s interface, so that
:class:`~basestation.sim.robot.SimulatedRobot` drives either; behind it is not the portable
core built for the host but the very image ``make -C firmware hex`` builds, executed
instruction by instruction on simavr's ATmega328P (``firmware/avrsim/board.c``, loaded as
``libamz_board.so`` through ctypes): its own ``loop()``, Arduino core, RFM69 driver,
timers, UART and EEPROM. A frame reaches it through the board's RFM69 (SPI), a GGA sentence
through its UART at 115 200 baud, the battery through ADC0; the motor is read back from its
pins (PWM duty on D9, enable D7, direction D8).

Time is the emulated chip's: ``now_ms`` is millisecond ``now_ms`` of its cycles, run up to
on each call and never back. Answering a frame runs the chip on until it starts to transmit
(bounded): the chip is then that far, about a millisecond, ahead of the robot's other models.

What the image cannot take: configuration overrides (its configuration is compiled in; the
agent's limits reach it over the air as on the roof), and the wheel sensor's velocity (the
default build has none; the image counts pulses on D3 only when built with one).
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import logging
import os
from pathlib import Path
from typing import Final

from basestation.protocol import codec
from basestation.protocol.errors import FrameError
from basestation.protocol.frames import TelemetryFrame
from basestation.sim.firmware import (
    FIRMWARE_DIR,
    MAX_FRAME_SIZE,
    AmzRobotConfig,
    FirmwareError,
    MotionOutput,
)

logger = logging.getLogger(__name__)

DEFAULT_ELF: Final = FIRMWARE_DIR / "build-nano-atmega328" / "robot.elf"
DEFAULT_BOARD_LIBRARY: Final = FIRMWARE_DIR / "avrsim" / "build" / "libamz_board.so"
#: Override where the image and the board library are (an installed agent has no tree).
ELF_ENV: Final = "AMZ_ROBOT_ELF"
BOARD_LIBRARY_ENV: Final = "AMZ_BOARD_LIBRARY"

F_CPU_HZ: Final = 16_000_000
CYCLES_PER_MS: Final = F_CPU_HZ // 1000
# The board's pins (firmware/robot/board.h): the local stop loop on D4 (PD4), HIGH = open.
LOCAL_STOP_PORT: Final = b"D"
LOCAL_STOP_BIT: Final = 4
# The sketch's e-stop latch in EEPROM byte 0 (robot.ino kEStopLatched).
EEPROM_E_STOP: Final = 0
E_STOP_LATCHED: Final = 0xE5
# The ADC: 10 bits of AVCC (5 V).
ADC_FULL_SCALE: Final = 1024
AVCC_MV: Final = 5000
# How long the image may take from a frame to its answer's start on the air: its loop
# comes round at least every 1.024 ms, and the longest pass is under 10 ms.
REPLY_WITHIN_MS: Final = 30


def _board_library() -> ctypes.CDLL:
    path = Path(os.environ.get(BOARD_LIBRARY_ENV) or DEFAULT_BOARD_LIBRARY)
    if not path.is_file():
        raise FirmwareError(
            f"{path} does not exist: run `make -C firmware avrsim` or set {BOARD_LIBRARY_ENV}"
        )
    return _load_board_library(path.resolve())


@functools.cache
def _load_board_library(path: Path) -> ctypes.CDLL:
    """The library with every prototype declared, once per process and path."""
    lib = ctypes.CDLL(str(path))
    board = ctypes.c_void_p
    u8p = ctypes.POINTER(ctypes.c_uint8)
    prototypes: dict[str, tuple[object, list[object]]] = {
        "amz_board_create": (board, [ctypes.c_char_p, ctypes.c_uint, ctypes.c_int]),
        "amz_board_destroy": (None, [board]),
        "amz_board_cycle": (ctypes.c_uint64, [board]),
        "amz_board_run_until": (ctypes.c_int, [board, ctypes.c_uint64]),
        "amz_board_air_in": (ctypes.c_int, [board, u8p, ctypes.c_int, ctypes.c_int]),
        "amz_board_air_out": (
            ctypes.c_int,
            [board, u8p, ctypes.c_int, ctypes.POINTER(ctypes.c_uint64)],
        ),
        "amz_board_uart_in": (ctypes.c_int, [board, u8p, ctypes.c_int]),
        "amz_board_set_battery_mv": (None, [board, ctypes.c_uint]),
        "amz_board_set_pin": (None, [board, ctypes.c_char, ctypes.c_int, ctypes.c_int]),
        "amz_board_set_eeprom": (ctypes.c_int, [board, ctypes.c_uint, ctypes.c_uint8]),
        "amz_board_motor": (
            None,
            [
                board,
                ctypes.POINTER(ctypes.c_uint),
                ctypes.POINTER(ctypes.c_int),
                ctypes.POINTER(ctypes.c_int),
            ],
        ),
        "amz_board_eeprom": (ctypes.c_int, [board, ctypes.c_uint]),
    }
    for name, (restype, argtypes) in prototypes.items():
        function = getattr(lib, name)
        function.restype = restype
        function.argtypes = argtypes
    return lib


class FlashedRobot:
    """The flashed image on one emulated board, behind ``FirmwareRobot``'s interface."""

    def __init__(
        self,
        config: AmzRobotConfig,
        *,
        elf: Path | str | None = None,
        e_stop_latched: bool = False,
    ) -> None:
        image = Path(elf or os.environ.get(ELF_ENV) or DEFAULT_ELF)
        if not image.is_file():
            raise FirmwareError(
                f"{image} does not exist: run `make -C firmware hex` or set {ELF_ENV}"
            )
        self.config = config
        self._lib = _board_library()
        handle = self._lib.amz_board_create(str(image).encode(), self._battery_mv(0), 1)
        if not handle:
            raise FirmwareError(f"{image} is not an ATmega328P image")
        self._board: int | None = handle
        self.image = image
        logger.info("robot: the flashed image %s on an emulated ATmega328P", image)
        if e_stop_latched:  # latched before this power-up, as the EEPROM would hold it
            self._lib.amz_board_set_eeprom(handle, EEPROM_E_STOP, E_STOP_LATCHED)
        self._duty = ctypes.c_uint()
        self._enable = ctypes.c_int()
        self._direction = ctypes.c_int()
        self._frame = (ctypes.c_uint8 * MAX_FRAME_SIZE)()
        self._sent_at = ctypes.c_uint64()
        self._last_telemetry: TelemetryFrame | None = None
        self._status = 0

    @property
    def board(self) -> int:
        if self._board is None:
            raise FirmwareError("the flashed robot was closed")
        return self._board

    def close(self) -> None:
        if self._board is not None:
            self._lib.amz_board_destroy(self._board)
            self._board = None

    def __del__(self) -> None:  # a forgotten close() must not leak the emulated board
        with contextlib.suppress(Exception):
            self.close()

    # --- time ---------------------------------------------------------------------------------

    def _run_to(self, now_ms: int) -> None:
        self._lib.amz_board_run_until(self.board, now_ms * CYCLES_PER_MS)
        self._take_sent()

    def _take_sent(self) -> list[bytes]:
        """What the image put on the air since the last look (its telemetry kept for status)."""
        sent = []
        while (
            n := self._lib.amz_board_air_out(
                self.board, self._frame, MAX_FRAME_SIZE, ctypes.byref(self._sent_at)
            )
        ) > 0:
            frame = bytes(self._frame[:n])
            sent.append(frame)
            with contextlib.suppress(FrameError):
                decoded = codec.decode_frame(frame)
                if isinstance(decoded, TelemetryFrame):
                    self._last_telemetry = decoded
                    self._status = int(decoded.status)
        return sent

    # --- FirmwareRobot's interface --------------------------------------------------------------

    def handle_frame(self, now_ms: int, frame: bytes, rssi_dbm: int) -> bytes:
        """A frame on the air for the robot (length byte first), received at ``rssi_dbm``;
        returns the answer the image starts to transmit within REPLY_WITHIN_MS, or b""."""
        self._run_to(now_ms)
        data = (ctypes.c_uint8 * len(frame)).from_buffer_copy(frame)
        if self._lib.amz_board_air_in(self.board, data, len(frame), int(rssi_dbm)) != 0:
            return b""  # the board's air already holds sixteen frames: this one is lost
        cycle = self._lib.amz_board_cycle(self.board)
        deadline = cycle + REPLY_WITHIN_MS * CYCLES_PER_MS
        while cycle < deadline:
            cycle = min(deadline, cycle + CYCLES_PER_MS // 4)
            self._lib.amz_board_run_until(self.board, cycle)
            sent = self._take_sent()
            if sent:
                return sent[-1]
        return b""

    def step(self, now_ms: int) -> MotionOutput:
        self._run_to(now_ms)
        self._lib.amz_board_motor(
            self.board,
            ctypes.byref(self._duty),
            ctypes.byref(self._enable),
            ctypes.byref(self._direction),
        )
        duty = self._duty.value
        direction = 1 if self._direction.value else 0
        enabled = bool(self._enable.value)
        applied = round(duty * self.config.full_scale_mm_s / max(1, self.config.duty_max))
        return MotionOutput(
            duty=duty,
            direction=direction,
            drive_enabled=enabled,
            status=self._status,
            velocity_mm_s=(applied if direction else -applied) if enabled else 0,
        )

    def add_battery_sample(self, adc_counts: int) -> None:
        """The battery at ADC0's pin, as ``adc_counts`` of the 10-bit converter would read it
        (the image samples it itself, every 20 ms)."""
        self._lib.amz_board_set_battery_mv(self.board, self._battery_mv(adc_counts))

    def feed_gps(self, now_ms: int, data: bytes) -> None:
        self._run_to(now_ms)
        buffer = (ctypes.c_uint8 * len(data)).from_buffer_copy(data)
        self._lib.amz_board_uart_in(self.board, buffer, len(data))

    def set_local_stop(self, open_: bool) -> None:
        self._lib.amz_board_set_pin(self.board, LOCAL_STOP_PORT, LOCAL_STOP_BIT, int(open_))

    def set_measured_velocity(self, now_ms: int, velocity_mm_s: int) -> None:
        """Not taken: the default image has no wheel sensor (see the module's text)."""
        del now_ms, velocity_mm_s

    @property
    def e_stop_latched(self) -> bool:
        return self._lib.amz_board_eeprom(self.board, EEPROM_E_STOP) == E_STOP_LATCHED

    def status(self, now_ms: int) -> int:
        """The status of the image's last telemetry (it reports only when asked)."""
        del now_ms
        return self._status

    @property
    def battery_10mv(self) -> int:
        telemetry = self._last_telemetry
        return int(telemetry.battery_10mv) if telemetry is not None else 0

    def _battery_mv(self, adc_counts: int) -> int:
        counts = adc_counts if adc_counts > 0 else 818  # a full battery until told otherwise
        return round(counts * AVCC_MV / ADC_FULL_SCALE)
