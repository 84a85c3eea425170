"""``python -m basestation.sim``: the robot as its own process, driven over UDP."""

from __future__ import annotations

import json
import queue
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from typing import IO, Any

import pytest

from basestation.protocol import (
    CommandFrame,
    Direction,
    TelemetryStatus,
    decode_telemetry,
    encode_command,
)
from basestation.sim.firmware import REPO_DIR
from basestation.sim.spi import SimulatedSpiConfig, make_simulated_spi
from tests.basestation.sim.driver import TinyDriver

# Only bounds a hang: how fast the robot answers and stops is measured by `make bench`.
HANG_S = 30.0
READY = re.compile(r"radio=udp://127\.0\.0\.1:(\d+) .* inspect=tcp://127\.0\.0\.1:(\d+)")


def inspect(port: int) -> dict[str, Any]:
    with socket.create_connection(("127.0.0.1", port), timeout=2.0) as connection:
        connection.sendall(b"state\n")
        data = connection.makefile("rb").readline()
    state: dict[str, Any] = json.loads(data)
    return state


def lines_of(stream: IO[str]) -> queue.Queue[str]:
    lines: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        for line in stream:
            lines.put(line)

    threading.Thread(target=pump, daemon=True).start()
    return lines


@pytest.fixture
def spi_and_robot(
    firmware_library: object,
) -> Iterator[tuple[Any, subprocess.Popen[str], int, queue.Queue[str]]]:
    spi = make_simulated_spi(SimulatedSpiConfig(transport="udp", base_port=0, robot_port=1))
    base_port = spi.channel.local_port  # type: ignore[union-attr]
    process = subprocess.Popen(
        [sys.executable, "-m", "basestation.sim", "--radio-port", "0", "--inspect-port", "0",
         "--peer-port", str(base_port), "--log-interval-s", "0.5"],
        cwd=REPO_DIR, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        assert process.stdout is not None
        lines = lines_of(process.stdout)
        ready = lines.get(timeout=20.0)
        match = READY.search(ready)
        assert match, ready
        spi.channel.connect(int(match.group(1)))  # type: ignore[union-attr]
        yield spi, process, int(match.group(2)), lines
    finally:
        process.terminate()
        process.wait(timeout=10)
        if process.stdout is not None:
            process.stdout.close()
        spi.close()


def test_the_robot_process_obeys_commands_and_stops_by_itself_when_they_stop(
    spi_and_robot: tuple[Any, subprocess.Popen[str], int, queue.Queue[str]],
) -> None:
    spi, process, inspect_port, lines = spi_and_robot
    driver = TinyDriver(spi, clock=time.monotonic, sleep=time.sleep)
    driver.begin()
    # 1 m/s CW at 20 Hz until the robot answers this very command and drives under it. How
    # many answers a busy machine loses is `make bench`'s to measure; the deadline only
    # bounds a hang.
    deadline_s = time.monotonic() + HANG_S
    seq, next_s = 0, time.monotonic()
    moving: dict[str, Any] | None = None
    while moving is None:
        assert time.monotonic() < deadline_s, "the robot never drove under our commands"
        seq += 1
        frame = encode_command(CommandFrame(seq=seq, velocity_mm_s=1000, direction=Direction.CW))
        answer = driver.exchange(frame, timeout_s=0.04)
        telemetry = None if answer is None else decode_telemetry(answer[0])
        if (
            telemetry is not None
            and telemetry.echo_seq == seq
            and TelemetryStatus.DEAD_MAN not in telemetry.status
        ):
            state = inspect(inspect_port)
            if state["velocity_mps"] > 0.3 and not state["dead_man"]:
                moving = state
        next_s += 0.05
        time.sleep(max(0.0, next_s - time.monotonic()))
    assert not moving["e_stop_latched"]

    # The agent goes silent (as if killed): the robot must stop on its own dead-man.
    deadline_s = time.monotonic() + HANG_S
    state = moving
    while state["velocity_mps"] != 0.0:
        assert time.monotonic() < deadline_s, f"the robot never stopped: {state}"
        time.sleep(0.1)
        state = inspect(inspect_port)
    assert state["dead_man"]
    assert state["track_m"] > moving["track_m"]
    assert process.poll() is None  # still running, stopped by itself

    logged = []
    while not lines.empty():
        logged.append(lines.get())
    assert any("status=DEAD_MAN" in line for line in logged), logged


def test_a_bad_config_stops_the_process_with_a_clear_error(tmp_path: Any) -> None:
    config = tmp_path / "bad.toml"
    config.write_text("[physics]\nmass_kg = 0\n", encoding="utf-8")
    result = subprocess.run(
        [sys.executable, "-m", "basestation.sim", "--config", str(config),
         "--radio-port", "0", "--inspect-port", "0"],
        cwd=REPO_DIR, capture_output=True, text=True, timeout=30, check=False,
    )  # fmt: skip
    assert result.returncode == 2
    assert "physics.mass_kg = 0 not in 1..1000" in result.stderr


def test_a_burst_of_signals_stops_the_robot_process(
    spi_and_robot: tuple[Any, subprocess.Popen[str], int, queue.Queue[str]],
) -> None:
    """Signals arriving while the handler of the one before runs (a stop of the process
    group on top of its supervisor's) must end the process, not hang it in the handler."""
    _, process, _, lines = spi_and_robot
    for n in range(2000):
        try:
            process.send_signal(signal.SIGTERM if n % 2 else signal.SIGINT)
        except ProcessLookupError:
            break
    assert process.wait(timeout=15) == 0
    logged = []
    while True:
        try:
            logged.append(lines.get(timeout=5))
        except queue.Empty:
            break
        if "robot stopped" in logged[-1]:
            break
    assert "amazing-sim: robot stopped" in logged[-1], logged
