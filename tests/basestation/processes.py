"""Starting the real agent (``python -m basestation`` under waitress) in a subprocess."""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from bench.stack import free_port

REPO_ROOT = Path(__file__).resolve().parents[2]
LISTENING = re.compile(r"listening on http://127\.0\.0\.1:(\d+)")


@dataclass
class Agent:
    process: subprocess.Popen[bytes]
    log_path: Path
    url: str

    @property
    def port(self) -> int:
        return int(self.url.rsplit(":", 1)[1])

    def log(self) -> str:
        return self.log_path.read_text(encoding="utf-8", errors="replace")

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait(10)


def agent_env(data_dir: Path, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("AGENT_")}
    env.update({"AGENT_DATA_DIR": str(data_dir), **extra})
    return env


def start_agent(data_dir: Path, log_path: Path, *, timeout_s: float = 15.0, **env: str) -> Agent:
    """Start an agent on a free port and wait until it listens (its log says where).

    The log is appended to, so a restarted agent can share its predecessor's log file.
    """
    before = len(LISTENING.findall(_read(log_path)))
    with log_path.open("ab") as log:
        process = subprocess.Popen(
            [sys.executable, "-m", "basestation", "--host", "127.0.0.1", "--port", "0"],
            cwd=REPO_ROOT,
            env=agent_env(data_dir, **env),
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    deadline = time.monotonic() + timeout_s
    ports: list[str] = []
    try:
        while len(ports) <= before and time.monotonic() < deadline and process.poll() is None:
            time.sleep(0.05)
            ports = LISTENING.findall(_read(log_path))
        assert len(ports) > before, _read(log_path)
    except BaseException:
        if process.poll() is None:
            process.kill()
        process.wait(10)
        raise
    return Agent(process=process, log_path=log_path, url=f"http://127.0.0.1:{ports[-1]}")


def _read(path: Path) -> str:
    return path.read_text(encoding="utf-8", errors="replace") if path.exists() else ""


@dataclass
class SimRobot:
    """The simulated robot in its own process (as on the roof), on the UDP radio."""

    process: subprocess.Popen[str]
    base_port: int
    robot_port: int
    inspect_port: int


@contextlib.contextmanager
def sim_robot_process() -> Iterator[SimRobot]:
    """``python -m basestation.sim`` started and ready; stopped on leaving."""
    from tests.basestation.sim.test_process import READY, lines_of

    base_port, robot_port = free_port(), free_port()
    robot = subprocess.Popen(
        [sys.executable, "-m", "basestation.sim", "--radio-port", str(robot_port),
         "--peer-port", str(base_port), "--inspect-port", "0"],
        cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        assert robot.stdout is not None
        ready = READY.search(lines_of(robot.stdout).get(timeout=20.0))
        assert ready, "the robot process did not say it was ready"
        yield SimRobot(robot, base_port, robot_port, int(ready.group(2)))
    finally:
        robot.terminate()
        robot.wait(10)
        if robot.stdout is not None:
            robot.stdout.close()
