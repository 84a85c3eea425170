"""The real agent process: ``python -m basestation`` under waitress, driven through AgentClient."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from basestation.client import AgentClient
from tests.basestation.conftest import TOKEN, run_body
from tests.basestation.processes import REPO_ROOT, Agent, agent_env, start_agent

pytestmark = pytest.mark.integration


@pytest.fixture
def agent_process(tmp_path: Path) -> Iterator[Agent]:
    agent = start_agent(tmp_path / "data", tmp_path / "agent.log", AGENT_TOKEN=TOKEN)
    try:
        yield agent
    finally:
        agent.kill()


def test_the_real_agent_runs_a_short_program_and_stops_cleanly(agent_process: Agent) -> None:
    with AgentClient(agent_process.url, TOKEN, timeout_s=5.0) as agent:
        assert agent.healthz() == {"ok": True}
        start_s = time.time() + 1.0
        # The ccw segment outlasts the reversal: ramp to zero, then the firmware's 700 ms
        # dwell at zero before the robot may drive the other way.
        segments = [
            {"velocity_mps": 0.4, "direction": "cw", "duration_s": 1.0},
            {"velocity_mps": 0.4, "direction": "ccw", "duration_s": 1.5},
        ]
        staged = agent.put_run("e2e", run_body(start_s, window_s=4.0, segments=segments))
        assert staged["state"] == "staged"

        deadline = time.monotonic() + 30.0  # only bounds a hang
        run = staged
        while run["state"] in ("staged", "running") and time.monotonic() < deadline:
            time.sleep(0.2)
            run = agent.get_run("e2e")
        assert run["state"] == "completed", run
        assert run["reason"] == "program finished"

        samples = list(agent.iter_samples("e2e", 0, limit=25))
        assert [s["seq"] for s in samples] == list(range(1, len(samples) + 1))
        assert run["sample_count"] == len(samples) == run["last_seq"]
        # A sample a tick within the run's window: how many ticks a busy machine skips (a
        # late tick skips its missed slots) is `make bench`'s to count.
        assert samples
        assert all(start_s <= s["t"] < start_s + 4.0 for s in samples)
        assert {s["direction"] for s in samples} == {"cw", "ccw"}

        status = agent.status()
        assert status["link"]["state"] == "up"
        assert status["current_run"] is None
        assert status["control"]["ticks"] >= len(samples)

    agent_process.process.send_signal(signal.SIGTERM)
    assert agent_process.process.wait(10) == 0
    log = agent_process.log()
    assert "run e2e: new -> staged" in log
    assert "run e2e: staged -> running" in log
    assert "run e2e: running -> completed (program finished)" in log
    assert "control 20 Hz" in log
    assert "agent stopped" in log


def test_the_real_agent_refuses_to_start_without_a_token(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "basestation", "--port", "0"],
        cwd=REPO_ROOT,
        env=agent_env(tmp_path / "data"),
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert result.returncode == 2
    assert "AGENT_TOKEN, AGENT_TOKEN_FILE or AGENT_TOKEN_SHA256 must be set" in result.stderr


def test_a_bad_rail_file_stops_the_agent_with_one_clear_line(tmp_path: Path) -> None:
    rail = tmp_path / "rail.json"
    rail.write_text('{"points": [{"lat": 40.6, "lon": -8.6}]}')
    env = agent_env(tmp_path / "data", AGENT_TOKEN=TOKEN, AGENT_RAIL_FILE=str(rail))
    result = subprocess.run(
        [sys.executable, "-m", "basestation", "--port", "0"],
        cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode == 2
    assert "configuration error: AGENT_RAIL_FILE: points: needs 3 to 500 points" in result.stderr
    assert "Traceback" not in result.stderr


def test_a_limit_above_the_robots_hard_maximum_stops_the_agent_with_one_clear_line(
    tmp_path: Path,
) -> None:
    # The simulated robot runs the firmware core, compiled with a 4 m/s hard maximum.
    env = agent_env(
        tmp_path / "data", AGENT_TOKEN=TOKEN, AGENT_ROBOT="sim", AGENT_MAX_VELOCITY_MPS="5"
    )
    result = subprocess.run(
        [sys.executable, "-m", "basestation", "--port", "0"],
        cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode == 2
    errors = [line for line in result.stderr.splitlines() if "configuration error" in line]
    assert errors == [
        "amazing-agent: configuration error: AGENT_MAX_VELOCITY_MPS=5 is above the robot's "
        "hard maximum 4 m/s (AMZ_HARD_MAX_VELOCITY_MM_S in its firmware)"
    ]
    assert "Traceback" not in result.stderr
