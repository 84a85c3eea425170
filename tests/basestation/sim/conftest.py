"""Fixtures for the simulator: the firmware library (built, never skipped) and a fake clock."""

from __future__ import annotations

import ctypes
import shutil
import subprocess

import pytest

from basestation.sim.clock import FakeClock
from basestation.sim.firmware import DEFAULT_LIBRARY, FIRMWARE_DIR, load_library


@pytest.fixture(scope="session")
def firmware_library() -> ctypes.CDLL:
    # Never skipped: a missing compiler is a broken test machine, not a passing test.
    assert shutil.which("make"), "make builds libamazing_robot.so"
    assert shutil.which("g++"), "g++ builds libamazing_robot.so"
    subprocess.run(
        ["make", "-s", "-C", str(FIRMWARE_DIR), "shared"], check=True, capture_output=True
    )
    return load_library(DEFAULT_LIBRARY, build=False)


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock(100.0)
