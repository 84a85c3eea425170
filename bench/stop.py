"""The emergency stop under HTTP load (DESIGN §8: a stop is served ahead of every other
request; target p95 ≤ 50 ms while 50 clients read).

The real agent (``python -m basestation``, waitress, its control loop at 50 Hz in a process
of its own, the simulated robot in another) is sent ``POST /api/v1/stop`` one at a time, each
released again, first with nobody else calling, then while 50 client threads read
``/status`` and ``/runs`` as fast as they can. The same is measured against the agent without
its CPU slots (``--cpu-slots 0``: every request thread competing for the interpreter lock)
and without its stop lane either (``--stop-threads 0``: stops queued with every other
request): the baselines of the same run on the same machine. Times are the
client's, from sending the stop to its answer (which the agent gives once the control loop
has latched it).
"""

from __future__ import annotations

import json
import secrets
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import requests

from bench.agent import (
    REPO,
    AgentProcess,
    ClientStats,
    RobotProcess,
)
from bench.stack import free_port
from bench.stats import percentile

TARGET_P95_MS = 50.0


def _read(url: str, token: str, done: threading.Event, stats: ClientStats, offset: int) -> None:
    session = requests.Session()
    session.headers["Authorization"] = f"Bearer {token}"
    paths = ("/api/v1/status", "/api/v1/runs")
    k = offset
    try:
        while not done.is_set():
            try:
                ok = session.get(url + paths[k % 2], timeout=10).status_code == 200
            except requests.RequestException:
                ok = False
            k += 1
            stats.requests += 1
            stats.errors += 0 if ok else 1
    finally:
        session.close()


def _stops(url: str, token: str, count: int, gap_s: float) -> list[float]:
    """``count`` stops, each released, from a process of their own (the readers' threads
    would otherwise hold this process's interpreter lock while a stop's answer waits for it);
    the stops' times in seconds."""
    script = (
        "import json, sys; from bench.stop import _timed_stops; "
        "print(json.dumps(_timed_stops(sys.argv[1], sys.argv[2], int(sys.argv[3]), "
        "float(sys.argv[4]))))"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, url, token, str(count), str(gap_s)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60 + count * 5,
        check=True,
    )
    times = json.loads(done.stdout)
    assert isinstance(times, list)
    return [float(t) for t in times]


def _timed_stops(url: str, token: str, count: int, gap_s: float) -> list[float]:
    session = requests.Session()
    session.headers["Authorization"] = f"Bearer {token}"
    times: list[float] = []
    try:
        for k in range(count):
            t0 = time.perf_counter()
            response = session.post(
                f"{url}/api/v1/stop", json={"user": "bench", "reason": f"stop {k}"}, timeout=10
            )
            times.append(time.perf_counter() - t0)
            if response.status_code != 200 or not response.json()["estop"]["latched"]:
                raise RuntimeError(f"stop {k} not latched: {response.status_code}")
            session.post(f"{url}/api/v1/stop/release", json={"user": "bench"}, timeout=30)
            time.sleep(gap_s)
    finally:
        session.close()
    return times


def _measure(
    scratch: Path,
    token: str,
    *,
    stop_threads: int,
    cpu_slots: int,
    stops: int,
    clients: int,
    hz: float,
) -> dict[str, Any]:
    base_port, robot_port = free_port(), free_port()
    robot = RobotProcess(robot_port, base_port)
    try:
        agent = AgentProcess(
            scratch,
            token,
            hz,
            8,
            AGENT_ROBOT="sim-udp",
            AGENT_SIM_BASE_PORT=str(base_port),
            AGENT_SIM_ROBOT_PORT=str(robot_port),
            extra_args=("--stop-threads", str(stop_threads), "--cpu-slots", str(cpu_slots)),
        )
    except BaseException:
        robot.stop()
        raise
    done = threading.Event()
    stats = [ClientStats() for _ in range(clients)]
    readers = [
        threading.Thread(target=_read, args=(agent.url, token, done, stats[i], i), daemon=True)
        for i in range(clients)
    ]
    try:
        idle = _stops(agent.url, token, stops, 0.02)
        for reader in readers:
            reader.start()
        time.sleep(1.0)  # the readers at full pace before the first stop
        reads_before = sum(s.requests for s in stats)
        started_s = time.monotonic()
        loaded = _stops(agent.url, token, stops, 0.02)
        load_s = time.monotonic() - started_s
        reads = sum(s.requests for s in stats) - reads_before
    finally:
        done.set()
        for reader in readers:
            if reader.is_alive():
                reader.join(15)
        agent.stop()
        robot.stop()
    return {"idle": idle, "loaded": loaded, "reads_per_s": reads / max(load_s, 1e-9)}


def _row(name: str, times: list[float]) -> str:
    def ms(fraction: float) -> str:
        value = percentile(times, fraction)
        return "—" if value is None else f"{value * 1000:.1f}"

    worst = max(times) * 1000 if times else float("nan")
    return f"| {name} | {len(times)} | {ms(0.50)} | {ms(0.95)} | {worst:.1f} |"


# The agent as it runs (the stop's lane and two CPU slots), and the same without each part.
VARIANTS = (
    ("stop lane + 2 CPU slots (as it runs)", 2, 2),
    ("stop lane, every thread running (`--cpu-slots 0`)", 2, 0),
    ("neither (`--stop-threads 0 --cpu-slots 0`)", 0, 0),
)


def run(
    *, stops: int = 200, clients: int = 50, hz: float = 50.0, variants: int = len(VARIANTS)
) -> str:
    """The report's markdown; ``variants``: the first that many of :data:`VARIANTS` (the
    smoke runs the agent as it runs only: each variant is the same path with other flags)."""
    token = secrets.token_urlsafe(24)
    results: list[tuple[str, dict[str, Any]]] = []
    for name, stop_threads, cpu_slots in VARIANTS[:variants]:
        with tempfile.TemporaryDirectory(prefix="amazing-bench-stop-") as scratch:
            measured = _measure(
                Path(scratch),
                token,
                stop_threads=stop_threads,
                cpu_slots=cpu_slots,
                stops=stops,
                clients=clients,
                hz=hz,
            )
        results.append((name, measured))
    running = results[0][1]
    p95_ms = (percentile(running["loaded"], 0.95) or 0.0) * 1000
    verdict = "met" if p95_ms <= TARGET_P95_MS else "**not met**"
    served = ", ".join(f"{r['reads_per_s']:.0f}" for _, r in results)
    rows = []
    for name, measured in results:
        rows.append(_row(f"{name}, idle", measured["idle"]))
        rows.append(_row(f"{name}, {clients} readers", measured["loaded"]))
    return "\n".join(
        [
            "## Emergency stop under HTTP load (agent)",
            "",
            f"`POST /api/v1/stop` (then released), {stops} times one after another, timed by "
            f"a client process of its own from sending to the answer; the real agent at "
            f"{hz:g} Hz with the simulated robot in a process of its own, 8 HTTP threads. "
            f"Under load, {clients} client threads read `/status` and `/runs` as fast as they "
            f"can (reads/s served, in the order of the rows: {served}).",
            "",
            "| agent | stops | p50 ms | p95 ms | max ms |",
            "| --- | --- | --- | --- | --- |",
            *rows,
            "",
            f"Target (DESIGN §8): p95 ≤ {TARGET_P95_MS:g} ms under load — {verdict} "
            f"({p95_ms:.1f} ms).",
        ]
    )
