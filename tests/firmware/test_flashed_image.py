"""The image `make firmware` builds, executed: robot.elf on simavr's emulated ATmega328P at
16 MHz (``firmware/avrsim/harness.c``), with the simulator's GPS sentences on its UART at
115 200 baud and 10 Hz and the battery on its ADC, timed in the chip's own cycles.

What only the real image can show (docs/firmware.md, "The flashed image on an emulated
chip"): it boots and its loop comes round, with the Arduino core, the timers, the UART and the
watchdog as built; the longest loop() pass and the stack's deepest point in painted RAM, each
against a floor; and a loop that hangs is cut off by the watchdog's interrupt, then the chip is
reset and boots again. The radio is absent here (the robot stays stopped and tries to start
its radio once a second, which is the longest pass).
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import pytest

from basestation.sim.gps import gga_sentence

FIRMWARE = Path(__file__).resolve().parents[2] / "firmware"
ELF = FIRMWARE / "build-nano-atmega328" / "robot.elf"
HARNESS = FIRMWARE / "avrsim" / "build" / "avr_harness"

# Three of the radio's restart attempts (one a second) and thirty GPS bursts.
EMULATED_S = 3.0
# The floors. A pass must come round well within a command period (50 Hz: 20 ms), so that a
# command waits at most one; the stack must leave the size check's reserve (firmware/Makefile
# STACK_RESERVE) free between its deepest point and the static data.
LOOP_MAX_FLOOR_US = 10_000.0
STACK_FREE_FLOOR_BYTES = 512
# The sketch's watchdog: 250 ms to its interrupt, another 250 ms to the reset (robot.ino).
WATCHDOG_PERIOD_US = 250_000.0


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
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["emulated_s"] == pytest.approx(EMULATED_S, abs=0.01)
    return result


def test_the_image_boots_and_keeps_its_loop_and_stack_within_their_floors(tmp_path):
    result = _run(tmp_path)
    assert result["resets"] == 0, result
    assert 0 < result["boot_us"] < 1_000_000, result
    # GPS bytes at the line's rate, every burst taken while the loop went round.
    assert result["gps_bytes"] >= EMULATED_S * 10 * 80, result
    assert result["passes"] >= EMULATED_S * 1_000_000 / LOOP_MAX_FLOOR_US, result
    assert result["loop_mean_us"] < result["loop_max_us"] <= LOOP_MAX_FLOOR_US, result
    assert result["stack_used_bytes"] > 0, result
    assert result["stack_free_bytes"] >= STACK_FREE_FLOOR_BYTES, result
    assert (
        result["data_end"] - 0x100 + result["stack_used_bytes"] + result["stack_free_bytes"]
        == result["ram_bytes"]
    ), result


def test_a_hung_loop_is_cut_off_by_the_watchdog_then_the_chip_resets_and_boots_again(tmp_path):
    result = _run(tmp_path, "1.0")
    assert result["resets"] == 1, result
    # Its interrupt (which removes the drive) one watchdog period after the hang, the reset
    # one more later; the oscillator of the watchdog is the chip's own, so within a tenth.
    assert result["hang_to_isr_us"] == pytest.approx(WATCHDOG_PERIOD_US, rel=0.1), result
    assert result["hang_to_reset_us"] == pytest.approx(2 * WATCHDOG_PERIOD_US, rel=0.1), result
    # Booted again and went round: passes after the reset, up to the run's end.
    after_reset_s = EMULATED_S - 1.0 - result["hang_to_reset_us"] / 1e6
    assert result["passes"] > (1.0 + after_reset_s) * 1_000_000 / LOOP_MAX_FLOOR_US, result
