"""The image `make firmware` builds, executed: robot.elf on simavr's emulated ATmega328P at
16 MHz (``firmware/avrsim/harness.c``), with the simulator's GPS sentences on its UART at
115 200 baud and 10 Hz and the battery on its ADC, timed in the chip's own cycles.

What only the real image can show (docs/firmware.md, "The flashed image on an emulated
chip"): it boots and its loop comes round, with the Arduino core, the timers, the UART and the
watchdog as built; the longest loop() pass and the stack's deepest point in painted RAM, each
against a floor (without a radio: the robot stays stopped and tries to start its radio once a
second, the longest pass). With an RFM69 on its SPI bus (the harness's register model) and the
base station's frames on the air, encoded by the portal's own codec: it answers "identify" with
the build id `make firmware` stamped, answers each command, and drives the motor's PWM as the
portable core does on the host, step for step, down to the dead-man's ramp; and a loop that
hangs while driving has its drive cut by the watchdog's interrupt, then the chip resets and
boots again.
"""

from __future__ import annotations

import json
import subprocess
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest

from basestation.protocol import codec
from basestation.protocol.frames import (
    NO_COMMAND_FLAGS,
    CommandFlag,
    CommandFrame,
    Direction,
    IdentifyFrame,
    IdentityFrame,
    TelemetryFrame,
    TelemetryStatus,
)
from basestation.sim.firmware import FirmwareRobot
from basestation.sim.gps import gga_sentence

FIRMWARE = Path(__file__).resolve().parents[2] / "firmware"
ELF = FIRMWARE / "build-nano-atmega328" / "robot.elf"
HARNESS = FIRMWARE / "avrsim" / "build" / "avr_harness"
# What `make firmware` stamped on this build (the same make run writes both).
BUILD_ID_HEADER = FIRMWARE / "host" / "build" / "build_id.h"

# Three of the radio's restart attempts (one a second) and thirty GPS bursts.
EMULATED_S = 3.0
# The floors. A pass must come round well within a command period (50 Hz: 20 ms), so that a
# command waits at most one; the stack must leave the size check's reserve (firmware/Makefile
# STACK_RESERVE) free between its deepest point and the static data.
LOOP_MAX_FLOOR_US = 10_000.0
STACK_FREE_FLOOR_BYTES = 512
# Idle with GPS sentences arriving, the chip is asleep most of the time (76 % measured).
ASLEEP_FLOOR = 0.5
# The sketch's watchdog: 250 ms to its interrupt, another 250 ms to the reset (robot.ino).
WATCHDOG_PERIOD_US = 250_000.0
# The base station's side: identify at 0.5 s, then a second of commands at 50 Hz.
IDENTIFY_AT_S = 0.5
COMMANDS_FROM_S = 0.6
COMMAND_PERIOD_S = 0.02
COMMANDS = 50
VELOCITY_MM_S = 500
DEAD_MAN_S = 0.5
# The battery the harness puts on ADC0, as the core counts it (60 V through the 15:1 divider:
# 4 V of 5 V, 10 bits).
BATTERY_ADC_COUNTS = 818


def _data_end() -> int:
    """The first RAM address above the static data: the ELF's ``_end``."""
    symbols = subprocess.run(
        ["avr-nm", str(ELF)], check=True, capture_output=True, text=True
    ).stdout
    for line in symbols.splitlines():
        fields = line.split()  # address, kind, name (undefined weak symbols have no address)
        if len(fields) == 3 and fields[2] == "_end":
            return int(fields[0], 16) & 0xFFFF
    raise AssertionError("robot.elf has no _end symbol")


def _commands(
    from_s: float, count: int, first_seq: int, flags: CommandFlag = NO_COMMAND_FLAGS
) -> list[tuple[float, bytes]]:
    """``count`` commands at 50 Hz from ``from_s``, clockwise at VELOCITY_MM_S."""
    return [
        (
            from_s + k * COMMAND_PERIOD_S,
            codec.encode_frame(
                CommandFrame(
                    seq=first_seq + k,
                    velocity_mm_s=VELOCITY_MM_S,
                    direction=Direction.CW,
                    flags=flags,
                )
            ),
        )
        for k in range(count)
    ]


def _air(
    tmp_path: Path, frames: list[tuple[float, bytes]] | None = None
) -> tuple[Path, list[tuple[float, bytes]]]:
    """The base station's frames, a line each: when it arrives, and its bytes (by default
    identify, then a second of commands)."""
    if frames is None:
        frames = [(IDENTIFY_AT_S, codec.encode_frame(IdentifyFrame(seq=1)))]
        frames += _commands(COMMANDS_FROM_S, COMMANDS, first_seq=10)
    path = tmp_path / "air.txt"
    path.write_text("".join(f"{at_s:.6f} {frame.hex()}\n" for at_s, frame in frames))
    return path, frames


def _lines(result: dict[str, Any], kind: str) -> list[list[str]]:
    return [line.split()[1:] for line in result["lines"] if line.startswith(kind + " ")]


def _core_duties(frames: list[tuple[float, bytes]], until_ms: int) -> dict[int, int]:
    """The portable core on the host, fed the same frames at the same times and stepped every
    millisecond: its PWM duty every 10 ms."""
    robot = FirmwareRobot(now_ms=0)
    pending = list(frames)
    duties = {}
    try:
        for now_ms in range(until_ms + 1):
            if now_ms % 20 == 0:
                robot.add_battery_sample(BATTERY_ADC_COUNTS)
            while pending and pending[0][0] * 1000 <= now_ms:
                robot.handle_frame(now_ms, pending.pop(0)[1], -60)
            out = robot.step(now_ms)
            if now_ms % 10 == 0:
                duties[now_ms] = out.duty
    finally:
        robot.close()
    return duties


def _run(tmp_path: Path, *extra: str) -> dict[str, Any]:
    assert ELF.exists(), f"{ELF} is missing: make test builds it (make -C firmware hex)"
    assert HARNESS.exists(), f"{HARNESS} is missing: make test builds it (make -C firmware avrsim)"
    gps = tmp_path / "gps.nmea"
    gps.write_bytes(
        b"".join(
            gga_sentence(
                utc_s_of_day=36_000 + k / 10,
                lat_deg=40.6331 + k * 1e-6,
                lon_deg=-8.6595,
                quality=4,
                satellites=14,
                hdop=0.7,
                differential_age_s=1.0,
            )
            for k in range(10)
        )
    )
    done = subprocess.run(
        [str(HARNESS), str(ELF), hex(_data_end()), str(EMULATED_S), str(gps), *extra],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    lines = done.stdout.strip().splitlines()
    result: dict[str, Any] = json.loads(lines[-1])
    assert result["emulated_s"] == pytest.approx(EMULATED_S, abs=0.01)
    result["lines"] = lines[:-1]
    return result


def test_the_image_boots_and_keeps_its_loop_and_stack_within_their_floors(tmp_path):
    result = _run(tmp_path)
    assert result["resets"] == 0, result
    assert 0 < result["boot_us"] < 1_000_000, result
    # GPS bytes at the line's rate, every burst taken while the loop went round.
    assert result["gps_bytes"] >= EMULATED_S * 10 * 80, result
    assert result["passes"] >= EMULATED_S * 1_000_000 / LOOP_MAX_FLOOR_US, result
    assert result["loop_mean_us"] < result["loop_max_us"] <= LOOP_MAX_FLOOR_US, result
    # Between passes the chip sleeps until an interrupt wakes it: the millisecond timer's
    # (every 1.024 ms, so a pass comes round at least that often) or a GPS byte's.
    assert result["passes"] >= EMULATED_S * 1000 / 1.024, result
    assert result["asleep_share"] >= ASLEEP_FLOOR, result
    assert result["stack_used_bytes"] > 0, result
    assert result["stack_free_bytes"] >= STACK_FREE_FLOOR_BYTES, result
    assert (
        result["data_end"] - 0x100 + result["stack_used_bytes"] + result["stack_free_bytes"]
        == result["ram_bytes"]
    ), result


def test_the_image_answers_identify_and_each_command_and_drives_as_the_core_does(tmp_path):
    air, frames = _air(tmp_path)
    result = _run(tmp_path, "--radio", str(air))
    assert result["resets"] == 0, result
    assert result["radio_received"] == len(frames), result
    # Answering (the reply's time on the air included) still comes round within the floor.
    assert result["loop_max_us"] <= LOOP_MAX_FLOOR_US, result
    sent = [(float(at), codec.decode_frame(bytes.fromhex(raw))) for at, raw in _lines(result, "tx")]
    identity = sent[0][1]
    assert isinstance(identity, IdentityFrame), sent[0]
    stamped = BUILD_ID_HEADER.read_text().split('"')[1]
    assert identity.build_id == stamped
    assert identity.dead_man_ms == DEAD_MAN_S * 1000
    telemetry = [frame for _, frame in sent[1:]]
    assert all(isinstance(frame, TelemetryFrame) for frame in telemetry), telemetry
    assert [frame.echo_seq for frame in telemetry] == [10 + k for k in range(COMMANDS)]  # type: ignore[union-attr]

    # The PWM as the image drives it (every 10 ms) against the core on the host: the same
    # to one step of 255, through the ramp up, the dead-man and the ramp down.
    motor = {round(float(at) * 1000): int(duty) for at, duty, _, _ in _lines(result, "motor")}
    core = _core_duties(frames, until_ms=round(EMULATED_S * 1000) - 10)
    assert max(motor.values()) > 5, motor
    assert max(motor.values()) == max(core.values())
    apart = {ms: (motor[ms], core[ms]) for ms in core if abs(motor[ms] - core[ms]) > 1}
    assert not apart, apart
    # Silence: the drive holds until the dead-man's time after the last command, then ramps
    # to 0 (a sample's worth of slack either side).
    last_command_ms = round((COMMANDS_FROM_S + (COMMANDS - 1) * COMMAND_PERIOD_S) * 1000)
    times = sorted(motor)
    falls_ms = min(b for a, b in pairwise(times) if motor[b] < motor[a])
    dead_man_ms = last_command_ms + DEAD_MAN_S * 1000
    # The duty only rises until then; one step of duty is 65 ms of the stop's deceleration,
    # so the first lower sample comes within that after the dead-man's time.
    assert dead_man_ms <= falls_ms <= dead_man_ms + 80, (falls_ms, motor)
    assert motor[times[-1]] == 0


def test_a_hung_loop_is_cut_off_by_the_watchdog_then_the_chip_resets_and_boots_again(tmp_path):
    air, _ = _air(tmp_path)
    hang_at_s = 1.2  # while driving
    result = _run(tmp_path, "--hang-at", str(hang_at_s), "--radio", str(air))
    assert result["resets"] == 1, result
    # Its interrupt (which removes the drive) one watchdog period after the hang, the reset
    # one more later; the oscillator of the watchdog is the chip's own, so within a tenth.
    assert result["hang_to_isr_us"] == pytest.approx(WATCHDOG_PERIOD_US, rel=0.1), result
    assert result["hang_to_reset_us"] == pytest.approx(2 * WATCHDOG_PERIOD_US, rel=0.1), result
    # Driving when it hung; the interrupt removes the drive (PWM and enable low) at once.
    motor = [(float(at), int(duty), int(enable)) for at, duty, enable, _ in _lines(result, "motor")]
    hung_s = result["hung_at_s"]
    assert hang_at_s <= hung_s < hang_at_s + 0.05, result
    isr_s = hung_s + result["hang_to_isr_us"] / 1e6
    held = [(d, e) for t, d, e in motor if hung_s - 0.05 <= t < isr_s]
    assert held, motor
    assert all(d > 0 and e == 1 for d, e in held), held
    cut = [(d, e) for t, d, e in motor if isr_s < t <= isr_s + 0.2]
    assert cut, motor
    assert all((d, e) == (0, 0) for d, e in cut), cut
    # Booted again and went round: passes after the reset, up to the run's end.
    after_reset_s = EMULATED_S - hang_at_s - result["hang_to_reset_us"] / 1e6
    assert result["passes"] > (hang_at_s + after_reset_s) * 1_000_000 / LOOP_MAX_FLOOR_US


def test_an_e_stop_is_kept_in_eeprom_through_a_reset_and_released_only_when_told(tmp_path):
    frames = [
        *_commands(0.6, 20, first_seq=10),  # driving
        *_commands(1.0, 1, first_seq=30, flags=CommandFlag.E_STOP),
        *_commands(1.7, 15, first_seq=31),  # after the reset: asked to drive, latched
        *_commands(2.1, 1, first_seq=46, flags=CommandFlag.E_STOP_RELEASE),
        *_commands(2.2, 25, first_seq=47),
    ]
    air, _ = _air(tmp_path, frames)
    result = _run(tmp_path, "--reset-at", "1.5", "--radio", str(air))
    assert result["resets"] == 1, result
    assert result["radio_received"] == len(frames), result
    # Released at the end: the latch's EEPROM byte is cleared again.
    assert result["eeprom0"] == 0, result
    telemetry = {
        frame.echo_seq: frame
        for _, raw in _lines(result, "tx")
        if isinstance(frame := codec.decode_frame(bytes.fromhex(raw)), TelemetryFrame)
    }
    latched = {
        seq for seq, frame in telemetry.items() if frame.status & TelemetryStatus.E_STOP_LATCHED
    }
    assert latched == set(range(30, 46)), sorted(latched)
    assert all(frame.battery_10mv == pytest.approx(6000, abs=20) for frame in telemetry.values())
    motor = [(float(at), int(duty), int(enable)) for at, duty, enable, _ in _lines(result, "motor")]
    assert any(d > 0 for t, d, _ in motor if t < 1.0)
    # From the stop (answered within a sample) to the release: no drive, before or after the
    # reset; driving again after it.
    assert all((d, e) == (0, 0) for t, d, e in motor if 1.01 <= t <= 2.1), motor
    assert any(d > 0 and e == 1 for t, d, e in motor if t > 2.2)


def test_the_latch_is_written_to_eeprom_when_the_stop_comes(tmp_path):
    frames = [*_commands(0.6, 5, first_seq=10), *_commands(0.8, 1, 20, CommandFlag.E_STOP)]
    air, _ = _air(tmp_path, frames)
    result = _run(tmp_path, "--radio", str(air))
    assert result["eeprom0"] == 0xE5, result  # robot.ino's kEStopLatched at address 0
