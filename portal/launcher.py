"""``make run``: the whole system on this machine, with the simulated robot.

Prepares the embedded setup (database, demo data, agent token) and then runs the system's
processes (``portal.processes``: the agent, the web server, the Celery workers, the collector
and beat; with ``ROBOTS=2`` a second agent and robot on a second rail) as children, each line
of their output prefixed with the process's name. Ctrl-C (or SIGTERM) stops every child and
its own children. A child that dies by itself is started again after a pause that doubles
with each death (``RESTART_DELAYS_S``), the rest going on serving; one that dies
``RESTART_LIMIT`` times within ``RESTART_WINDOW_S`` is left stopped and so is everything else,
with the reason and a non-zero exit code: a fault that comes back at once is a set-up problem
to read, not to hide.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from core.fleet import SECOND_ROBOT
from portal.processes import system_processes

BASE_DIR = Path(__file__).resolve().parent.parent
STOP_GRACE_S = 10.0
# Pauses before a dead child is started again: 1 s, then doubling, at most 30 s.
RESTART_DELAYS_S = (1.0, 2.0, 4.0, 8.0, 16.0, 30.0)
RESTART_LIMIT = 5
RESTART_WINDOW_S = 600.0
# How often the children are looked at (a death is noticed, a pause found over).
WATCH_INTERVAL_S = 0.5


@dataclass
class Child:
    name: str
    argv: list[str]
    env: dict[str, str] = field(default_factory=dict)
    process: subprocess.Popen[bytes] | None = None
    pump: threading.Thread | None = field(default=None, repr=False)
    # When it died by itself, most recent last; and when it is due to start again.
    deaths: list[float] = field(default_factory=list)
    restart_at: float | None = None

    def died(self, now: float) -> float | None:
        """Note a death at ``now``; the pause before the next start, or ``None`` when the
        child has died too often to be started again."""
        self.deaths = [t for t in self.deaths if now - t < RESTART_WINDOW_S] + [now]
        if len(self.deaths) > RESTART_LIMIT:
            return None
        return RESTART_DELAYS_S[min(len(self.deaths), len(RESTART_DELAYS_S)) - 1]


_OUTPUT_LOCK = threading.Lock()


def _say(name: str, line: str) -> None:
    with _OUTPUT_LOCK:
        sys.stdout.write(f"{name:<7}| {line}\n")
        sys.stdout.flush()


def _pump(child: Child) -> None:
    assert child.process is not None
    assert child.process.stdout is not None
    for raw in child.process.stdout:
        _say(child.name, raw.decode(errors="replace").rstrip())


def _environment(var_dir: Path) -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("DJANGO_DEBUG", "1")
    env.setdefault("AMAZING_VAR_DIR", str(var_dir))
    env["PYTHONUNBUFFERED"] = "1"
    portal_port = int(env.setdefault("PORTAL_PORT", "8000"))
    # The live streams on their own port of the same host: the pages open them there.
    env.setdefault("LIVE_STREAM_PORT", env.setdefault("STREAMS_PORT", str(portal_port + 1)))
    agent_port = int(env.setdefault("AGENT_PORT", "8700"))
    if "DATABASE_URL" not in env:
        # SQLite takes one writer at a time: more web processes would only queue on its lock.
        env.setdefault("WEB_WORKERS", "1")
    env.setdefault("AGENT_URL", f"http://127.0.0.1:{agent_port}")
    env.setdefault("AGENT_DATA_DIR", str(var_dir / "agent"))
    if "AGENT_TOKEN" not in env and "AGENT_TOKEN_FILE" not in env:
        env["AGENT_TOKEN_FILE"] = str(_token_file(var_dir / "agent-token"))
    env.setdefault("DJANGO_ALLOWED_HOSTS", "127.0.0.1,localhost")
    if "SCHEDULER_URL" not in env:
        # No testbed scheduler given: the stand-in plays it, and owns the fixed nodes.
        standin_port = int(env.setdefault("STANDIN_PORT", "8710"))
        env["SCHEDULER_URL"] = f"http://127.0.0.1:{standin_port}"
        env["_STANDIN"] = "1"
    env["_PORTAL_PORT"] = str(portal_port)
    robots = env.setdefault("ROBOTS", "1")
    if robots not in ("1", "2"):
        raise SystemExit(f"ROBOTS is 1 or 2, not {robots!r}")
    if robots == "2":
        second_port = int(env.setdefault("AGENT_2_PORT", str(agent_port + 1)))
        env.setdefault("AGENT_2_URL", f"http://127.0.0.1:{second_port}")
        # The second agent's own token: in its file for the agent, by name for the portal.
        token = _token_file(var_dir / "agent-2-token").read_text().strip()
        tokens_file = var_dir / "agent-tokens"
        tokens_file.write_text(f"{SECOND_ROBOT}={token}\n")
        tokens_file.chmod(0o600)
        env.setdefault("AGENT_TOKENS_FILE", str(tokens_file))
    return env


def _token_file(path: Path) -> Path:
    """A random token in ``path``, made the first time."""
    if not path.exists():
        path.write_text(secrets.token_urlsafe(32))
        path.chmod(0o600)
    return path


def _manage(env: dict[str, str], *args: str) -> None:
    subprocess.run([sys.executable, "manage.py", *args], cwd=BASE_DIR, env=env, check=True)


def _port_free(port: int) -> bool:
    with socket.socket() as sock:
        return sock.connect_ex(("127.0.0.1", port)) != 0


def _wait_for_port(port: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not _port_free(port):
            return True
        time.sleep(0.2)
    return False


def _stop(children: list[Child]) -> None:
    """SIGTERM each child's process group, then SIGKILL whatever is left after the grace time."""
    for child in children:
        if child.process and child.process.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(child.process.pid, signal.SIGTERM)
    deadline = time.monotonic() + STOP_GRACE_S
    for child in children:
        if child.process is None:
            continue
        try:
            child.process.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            _say("launch", f"{child.name} did not stop in {STOP_GRACE_S:g} s; killing it")
        # Reap stragglers of the group (a worker's pool processes) even if the leader exited.
        with contextlib.suppress(ProcessLookupError):
            os.killpg(child.process.pid, signal.SIGKILL)
        child.process.wait()
        if child.pump:
            child.pump.join(timeout=2)


def _start(child: Child, env: dict[str, str]) -> None:
    child.process = subprocess.Popen(
        child.argv,
        cwd=BASE_DIR,
        env={**env, **child.env},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        start_new_session=True,  # own process group: stopped as a whole
    )
    child.pump = threading.Thread(target=_pump, args=(child,), daemon=True)
    child.pump.start()
    _say("launch", f"started {child.name} (pid {child.process.pid})")


def _watch(children: list[Child], env: dict[str, str]) -> int:
    """One look at the children: start again those whose pause is over, note those that have
    died. Non-zero when one has died too often and everything should stop."""
    now = time.monotonic()
    for child in children:
        if child.restart_at is not None:
            if now >= child.restart_at:
                child.restart_at = None
                if child.pump:
                    child.pump.join(timeout=2)
                _start(child, env)
            continue
        assert child.process is not None
        code = child.process.poll()
        if code is None:
            continue
        # Whatever the child left behind in its process group (a worker's pool) goes too.
        with contextlib.suppress(ProcessLookupError):
            os.killpg(child.process.pid, signal.SIGKILL)
        pause_s = child.died(now)
        if pause_s is None:
            _say(
                "launch",
                f"{child.name} exited with code {code}, its {len(child.deaths)}th exit within "
                f"{RESTART_WINDOW_S:g} s; not starting it again: stopping the rest",
            )
            return 1
        _say(
            "launch",
            f"{child.name} exited with code {code}; starting it again in {pause_s:g} s "
            f"(exit {len(child.deaths)} of at most {RESTART_LIMIT} within {RESTART_WINDOW_S:g} s)",
        )
        child.restart_at = now + pause_s
    return 0


class _Stopping:
    """Set by SIGINT or SIGTERM; the watch loop reads it between looks."""

    requested = False


def main() -> int:
    var_dir = Path(os.environ.get("AMAZING_VAR_DIR", BASE_DIR / "var")).resolve()
    var_dir.mkdir(parents=True, exist_ok=True)
    env = _environment(var_dir)
    portal_port = int(env["PORTAL_PORT"])
    streams_port = int(env["STREAMS_PORT"])
    agent_port = int(env["AGENT_PORT"])
    standin_port = int(env["STANDIN_PORT"]) if env.get("_STANDIN") else None
    second_port = int(env["AGENT_2_PORT"]) if env["ROBOTS"] == "2" else None
    ports = [
        ("portal", "PORTAL_PORT", portal_port),
        ("live streams", "STREAMS_PORT", streams_port),
        ("agent", "AGENT_PORT", agent_port),
    ]
    if second_port is not None:
        ports.append(("second agent", "AGENT_2_PORT", second_port))
    if standin_port is not None:
        ports.append(("stand-in scheduler", "STANDIN_PORT", standin_port))
    for name, variable, port in ports:
        if not _port_free(port):
            _say("launch", f"port {port} for the {name} is taken; set {variable}")
            return 2

    _say("launch", f"database: {env.get('DATABASE_URL', 'SQLite in ' + str(var_dir))}")
    _say("launch", f"task broker: {env.get('CELERY_BROKER_URL', 'filesystem (no server)')}")
    _say(
        "launch",
        f"testbed scheduler: {env['SCHEDULER_URL']}"
        + (" (the stand-in)" if standin_port is not None else ""),
    )
    _say("launch", f"live updates: {env.get('REDIS_URL') or 'files in ' + str(var_dir / 'live')}")
    workers = env.get("WEB_WORKERS") or f"{os.cpu_count() or 1} (one per core)"
    _say(
        "launch",
        f"web: {workers} worker process(es) on port {portal_port}"
        + (" (SQLite takes one writer at a time)" if "DATABASE_URL" not in env else "")
        + f"; live streams on port {streams_port}",
    )
    children = [
        Child(spec.name, list(spec.argv), dict(spec.env))
        for spec in system_processes(
            python=sys.executable,
            portal_port=portal_port,
            streams_port=streams_port,
            agent_port=agent_port,
            var_dir=var_dir,
            access_log=False,  # a line per request would drown everything else
            standin_port=standin_port,
            second_agent_port=second_port,
        )
    ]
    # The demo's node measures too: the experimenter's runs get a synthetic signal strength
    # pushed through the API while they run (the run page's heatmap), with a token
    # demo_setup writes.
    rssi_token = var_dir / "demo-rssi-token"
    portal_url = f"http://127.0.0.1:{portal_port}"
    rssi = ["--watch", "--portal", portal_url, "--token-file", str(rssi_token)]
    children.append(Child("rssi", [sys.executable, "-m", "basestation.sim.rssi", *rssi]))

    # A plain flag, not a threading.Event: Ctrl-C and a SIGTERM together (or a SIGTERM to the
    # whole group) run the handler again while it is inside Event.set, whose lock is not
    # reentrant, and the launcher would hang with every child running.
    stopping = _Stopping()

    def on_signal(signum: int, _frame: object) -> None:
        stopping.requested = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)

    exit_code = 0
    try:
        set_up = False
        for child in children:
            if child.name != "scheduler" and not set_up:
                # The stand-in, if any, is up first: it lists the fixed nodes demo_setup makes.
                _manage(env, "migrate", "--no-input", "-v", "0")
                second = ["--second-robot", env["AGENT_2_URL"]] if second_port is not None else []
                _manage(env, "demo_setup", "--rssi-token-file", str(rssi_token), *second)
                set_up = True
            _start(child, env)
            stand_in = child.name == "scheduler" and standin_port is not None
            if stand_in and not _wait_for_port(standin_port or 0, 30):
                _say("launch", "the stand-in scheduler did not start; stopping")
                return 1
        if _wait_for_port(portal_port, 60):
            _say(
                "launch",
                f"ready: log in at http://127.0.0.1:{portal_port}/ "
                "(users admin and experimenter; passwords were printed when they were created)",
            )
            _say(
                "launch",
                f"API docs at http://127.0.0.1:{portal_port}/api/docs/ ; Ctrl-C stops everything",
            )
        while not stopping.requested:
            exit_code = _watch(children, env)
            if exit_code:
                break
            time.sleep(WATCH_INTERVAL_S)
    finally:
        _say("launch", "stopping…")
        _stop(children)
        _say("launch", "all processes stopped")
    return exit_code


if __name__ == "__main__":
    sys.exit(main())
