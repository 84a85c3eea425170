"""Run start and emergency stop, timed on the air (DESIGN §6).

- Run start: the first command frame that moves the robot goes on the air within one
  control tick of the run's ``start_at``.
- E-stop: from the moment ``POST /stop`` is sent to the moment the frame with the stop flag
  starts on the air: at most one tick.

The real agent runs as ``python -m basestation`` (its control loop in a process of its own,
so the stop goes HTTP process → loop process → radio) with ``AGENT_ROBOT=sim-udp``: the
RFM69 driver on the emulated chip, whose air reaches the simulated robot (firmware core on
rail physics, ``python -m basestation.sim``) in another process. This bench sits on that air
between the two: it relays every datagram and notes when each command frame starts on the
air (the sender's start, on ``time.monotonic``, the clock every process shares), which is
what is timed: not the agent's own idea of when it sent.
"""

from __future__ import annotations

import io
import json
import secrets
import socket
import statistics
import struct
import tempfile
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import requests

from bench.agent import AgentProcess, RobotProcess, realtime
from bench.stack import free_port

TICK_S = 0.05  # 20 Hz, the agent's default
STARTS = 20
STOPS = 40
# Linux: the kernel stamps each datagram's arrival (struct timespec, wall clock).
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)


def _iso(epoch_s: float) -> str:
    return datetime.fromtimestamp(epoch_s, UTC).isoformat().replace("+00:00", "Z")


class AirLog:
    """The simulated air between the agent's chip and the robot, relayed by this process:
    command frames are kept with their start on the air (monotonic clock)."""

    def __init__(self, robot_port: int) -> None:
        self.lock = threading.Lock()
        self.frames: list[tuple[float, Any]] = []  # (start on the air, CommandFrame)
        self.robot_port = robot_port
        self.base_port: int | None = None
        # The agent's chip sends here; the robot answers to the other socket.
        self.towards_robot = self._socket()
        self.towards_base = self._socket()
        self._closed = False
        self._threads = [
            threading.Thread(target=self._relay, args=(self.towards_robot, True), daemon=True),
            threading.Thread(target=self._relay, args=(self.towards_base, False), daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    @staticmethod
    def _socket() -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(0.2)
        # The kernel's arrival time of each datagram: what this relay notes does not depend
        # on when its thread gets the CPU.
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        return sock

    @staticmethod
    def _arrival_s(ancillary: list[tuple[int, int, bytes]]) -> float:
        """The datagram's arrival on the monotonic clock (now, without a kernel stamp)."""
        for level, kind, data in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(data) >= 16:
                seconds, nanoseconds = struct.unpack("qq", data[:16])
                return seconds + nanoseconds / 1e9 - (time.time() - time.monotonic())
        return time.monotonic()

    @property
    def agent_peer_port(self) -> int:
        return int(self.towards_robot.getsockname()[1])

    @property
    def robot_peer_port(self) -> int:
        return int(self.towards_base.getsockname()[1])

    def _relay(self, sock: socket.socket, from_agent: bool) -> None:
        from basestation.protocol.codec import decode_frame
        from basestation.protocol.frames import CommandFrame

        realtime(0)
        while not self._closed:
            try:
                payload, ancillary, _, (_, port) = sock.recvmsg(65536, 256)
            except TimeoutError:
                continue
            except OSError:
                return
            received_s = self._arrival_s(ancillary)
            if from_agent:
                self.base_port = port
                try:
                    message = json.loads(payload)
                    if message.get("kind") == "frame":
                        decoded = decode_frame(bytes.fromhex(message["data"]))
                        if isinstance(decoded, CommandFrame):
                            with self.lock:
                                self.frames.append((received_s + message["delay_s"], decoded))
                except (ValueError, KeyError, TypeError):
                    pass
                self.towards_base.sendto(payload, ("127.0.0.1", self.robot_port))
            elif self.base_port is not None:
                self.towards_robot.sendto(payload, ("127.0.0.1", self.base_port))

    def first_after(self, since_s: float, matches: Any, timeout_s: float) -> float | None:
        deadline_s = time.monotonic() + timeout_s
        while time.monotonic() < deadline_s:
            with self.lock:
                for start_s, frame in self.frames:
                    if start_s >= since_s and matches(frame):
                        return start_s
            time.sleep(0.002)
        return None

    def close(self) -> None:
        self._closed = True
        for thread in self._threads:
            thread.join(2.0)
        self.towards_robot.close()
        self.towards_base.close()


def _ms(values: list[float]) -> str:
    ordered = sorted(values)
    p95 = ordered[int(0.95 * (len(ordered) - 1))]
    return (
        f"{statistics.median(values) * 1000:.1f} ms | {p95 * 1000:.1f} ms | "
        f"{ordered[-1] * 1000:.1f} ms"
    )


def run(*, starts: int = STARTS, stops: int = STOPS) -> str:
    from basestation.protocol.frames import CommandFlag

    token = secrets.token_hex(16)
    base_port, robot_port = free_port(), free_port()
    air = AirLog(robot_port)
    with tempfile.TemporaryDirectory() as scratch:
        # The robot answers to the relay's far side, which passes it on to the agent's chip.
        robot = RobotProcess(robot_port, air.robot_peer_port)
        agent: AgentProcess | None = None
        try:
            agent = AgentProcess(
                Path(scratch),
                token,
                1.0 / TICK_S,
                8,
                AGENT_ROBOT="sim-udp",
                AGENT_SIM_BASE_PORT=str(base_port),
                AGENT_SIM_ROBOT_PORT=str(air.agent_peer_port),
            )
            start_lateness_s, stop_latency_s = _measure(
                agent.url, token, air, starts, stops, CommandFlag.E_STOP
            )
        finally:
            if agent is not None:
                agent.stop()
            air.close()
            robot.stop()
    return _report(start_lateness_s, stop_latency_s, robot_realtime=robot.realtime)


def _measure(
    url: str, token: str, air: AirLog, starts: int, stops: int, e_stop: int
) -> tuple[list[float], list[float]]:
    http = requests.Session()
    http.headers["Authorization"] = f"Bearer {token}"
    try:
        start_lateness_s: list[float] = []
        for k in range(starts):
            # Any phase of the tick: the start falls anywhere between two ticks.
            start_s = time.time() + 1.0 + secrets.randbelow(1000) / 1000.0 * TICK_S
            body = {
                "owner": "bench",
                "title": f"start {k}",
                "start_at": _iso(start_s),
                "end_at": _iso(start_s + 3.0),
                "segments": [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 0.5}],
                "limits": {"max_velocity_mps": 1.0, "max_accel_mps2": 1.0},
            }
            staged = http.put(f"{url}/api/v1/runs/start-{k}", json=body, timeout=10)
            assert staged.status_code == 201, staged.text
            # start_at is wall-clock; the air is timed on the monotonic clock.
            start_mono_s = start_s - (time.time() - time.monotonic())
            moved = air.first_after(
                start_mono_s - 1.0, lambda f: f.velocity_mm_s > 0, timeout_s=5.0
            )
            assert moved is not None, "no moving command frame after the start"
            start_lateness_s.append(moved - start_mono_s)
            http.delete(f"{url}/api/v1/runs/start-{k}", timeout=10)  # frees the robot
            time.sleep(0.6)  # ramp down before the next start

        stop_latency_s: list[float] = []
        for _ in range(stops):
            time.sleep(secrets.randbelow(1000) / 1000.0 * TICK_S)
            sent_s = time.monotonic()
            answer = http.post(f"{url}/api/v1/stop", json={"reason": "bench"}, timeout=10)
            assert answer.status_code == 200, answer.text
            on_air = air.first_after(sent_s, lambda f: bool(f.flags & e_stop), timeout_s=2.0)
            assert on_air is not None, "no stop frame on the air"
            stop_latency_s.append(on_air - sent_s)
            released = http.post(f"{url}/api/v1/stop/release", timeout=10)
            assert released.status_code == 200, released.text
            time.sleep(0.1)
    finally:
        http.close()
    return start_lateness_s, stop_latency_s


def _report(
    start_lateness_s: list[float], stop_latency_s: list[float], *, robot_realtime: bool
) -> str:
    out = io.StringIO()
    out.write("## Run start and emergency stop, timed on the air\n\n")
    out.write(
        "The real agent (`python -m basestation`, waitress on 127.0.0.1, its control loop "
        "at 20 Hz in a process of its own) with the simulated robot in another process "
        "behind the real RFM69 driver on the emulated chip; times are when the base "
        "station's chip starts the frame on the air (monotonic clock, from the kernel's "
        "arrival stamp of each datagram at a relay on the simulated air). The simulated "
        "robot and the relay "
        + (
            "run under SCHED_FIFO (priority 5, below the agent's loop)"
            if robot_realtime
            else "run at normal priority (SCHED_FIFO refused)"
        )
        + ": the real robot is a microcontroller that never waits for a CPU. Target for "
        f"both: within one tick ({TICK_S * 1000:.0f} ms).\n\n"
    )
    out.write("| what | n | median | p95 | max | target |\n| --- | --- | --- | --- | --- | --- |\n")
    out.write(
        f"| first moving command frame after `start_at` | {len(start_lateness_s)} | "
        f"{_ms(start_lateness_s)} | ≤ {TICK_S * 1000:.0f} ms |\n"
    )
    out.write(
        f"| `POST /stop` sent → stop frame on the air | {len(stop_latency_s)} | "
        f"{_ms(stop_latency_s)} | ≤ {TICK_S * 1000:.0f} ms |\n"
    )
    early = [s for s in start_lateness_s if s < 0]
    if early:
        out.write(
            f"\n{len(early)} start(s) moved before `start_at` (by at most "
            f"{-min(early) * 1000:.1f} ms).\n"
        )
    return out.getvalue()
