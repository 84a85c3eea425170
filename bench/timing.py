"""Run start and emergency stop, timed on the air (DESIGN §6).

- Run start: the first command frame that moves the robot goes on the air within one
  control tick of the run's ``start_at``.
- E-stop: from the moment ``POST /stop`` is sent to the moment the frame with the stop flag
  starts on the air: at most one tick.

The real agent runs in this process with its control-loop thread and the simulated robot
(the RFM69 driver on the emulated chip, the firmware core on rail physics), behind a real
waitress HTTP server; requests come over 127.0.0.1. The base station's emulated chip
reports every frame it puts on the air with its start time on the channel's clock
(``time.monotonic``), which is what is timed: not the agent's own idea of when it sent.
"""

from __future__ import annotations

import io
import secrets
import statistics
import tempfile
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import requests

TICK_S = 0.05  # 20 Hz, the agent's default
STARTS = 20
STOPS = 40


def _iso(epoch_s: float) -> str:
    return datetime.fromtimestamp(epoch_s, UTC).isoformat().replace("+00:00", "Z")


class AirLog:
    """Command frames as the base station's chip puts them on the air."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.frames: list[tuple[float, Any]] = []  # (start on the air, CommandFrame)

    def attach(self, chip: Any) -> None:
        from basestation.protocol.codec import decode_frame
        from basestation.protocol.frames import CommandFrame

        port = chip._port  # the chip's place on the simulated air
        transmit = port.transmit

        def logged(frame: Any) -> Any:
            try:
                decoded = decode_frame(frame.data)
            except ValueError:
                decoded = None
            if isinstance(decoded, CommandFrame):
                with self.lock:
                    self.frames.append((frame.start_s, decoded))
            return transmit(frame)

        port.transmit = logged

    def first_after(self, since_s: float, matches: Any, timeout_s: float) -> float | None:
        deadline_s = time.monotonic() + timeout_s
        while time.monotonic() < deadline_s:
            with self.lock:
                for start_s, frame in self.frames:
                    if start_s >= since_s and matches(frame):
                        return start_s
            time.sleep(0.002)
        return None


def _serve(app: Any) -> tuple[Any, str]:
    from waitress.server import create_server

    server = create_server(app, host="127.0.0.1", port=0, threads=8)
    threading.Thread(target=server.run, name="http", daemon=True).start()
    port = getattr(server, "effective_port", None)  # one TCP socket: a TcpWSGIServer
    return server, f"http://127.0.0.1:{port}"


def _ms(values: list[float]) -> str:
    ordered = sorted(values)
    p95 = ordered[int(0.95 * (len(ordered) - 1))]
    return (
        f"{statistics.median(values) * 1000:.1f} ms | {p95 * 1000:.1f} ms | "
        f"{ordered[-1] * 1000:.1f} ms"
    )


def run(*, starts: int = STARTS, stops: int = STOPS) -> str:
    from basestation.app import create_app
    from basestation.config import AgentConfig
    from basestation.protocol.frames import CommandFlag
    from basestation.runtime import get_runtime

    token = secrets.token_hex(16)
    with tempfile.TemporaryDirectory() as data_dir:
        config = AgentConfig(token=token, data_dir=Path(data_dir), robot="sim")
        app = create_app(config)
        runtime = get_runtime(app)
        air = AirLog()
        air.attach(runtime.manager.robot.radio.spi.chip)  # type: ignore[attr-defined]
        server, url = _serve(app)
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
                on_air = air.first_after(
                    sent_s, lambda f: bool(f.flags & CommandFlag.E_STOP), timeout_s=2.0
                )
                assert on_air is not None, "no stop frame on the air"
                stop_latency_s.append(on_air - sent_s)
                released = http.post(f"{url}/api/v1/stop/release", timeout=10)
                assert released.status_code == 200, released.text
                time.sleep(0.1)
        finally:
            server.close()
            runtime.close()

    out = io.StringIO()
    out.write("## Run start and emergency stop, timed on the air\n\n")
    out.write(
        "The agent in process with its control loop (20 Hz) and the simulated robot behind "
        "the real RFM69 driver, waitress on 127.0.0.1; times are when the base station's "
        "emulated chip starts the frame on the air (monotonic clock). Target for both: "
        f"within one tick ({TICK_S * 1000:.0f} ms).\n\n"
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
