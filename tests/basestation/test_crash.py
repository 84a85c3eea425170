"""The real agent killed with SIGKILL in the middle of a run, then restarted on the same data.

Every sample the agent served before the kill is there after the restart, identical and
exactly once; the numbering has no gap; the run says it was interrupted. With the simulated
robot in its own process, the robot stops by itself on its dead-man.
"""

from __future__ import annotations

import http.client
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import requests

from basestation.app import MAX_BODY_BYTES
from basestation.client import AgentClient
from tests.basestation.conftest import TOKEN, run_body
from tests.basestation.processes import Agent, sim_robot_process, start_agent

pytestmark = pytest.mark.integration


@pytest.fixture
def agents(tmp_path: Path) -> Iterator[list[Agent]]:
    started: list[Agent] = []
    yield started
    for agent in started:
        agent.kill()


def _wait_for(condition: Any, timeout_s: float = 30.0) -> Any:
    """``condition``'s first truthy value; the deadline only bounds a hang."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError("timed out")


def test_a_killed_agent_keeps_every_served_sample_exactly_once_and_marks_the_run_interrupted(
    tmp_path: Path, agents: list[Agent]
) -> None:
    data_dir, log_path = tmp_path / "data", tmp_path / "agent.log"
    agent = start_agent(data_dir, log_path, AGENT_TOKEN=TOKEN)
    agents.append(agent)
    with AgentClient(agent.url, TOKEN) as client:
        start_s = time.time() + 0.5
        segments = [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 60.0}]
        client.put_run("crash", run_body(start_s, window_s=120.0, segments=segments))
        _wait_for(lambda: client.get_run("crash")["sample_count"] >= 30)
        # Read while the agent writes: whatever it has served must survive the kill.
        served = list(client.iter_samples("crash", 0, limit=7))
        agent.process.kill()  # SIGKILL: no clean-up of any kind in the agent's process
        agent.process.wait(10)
    assert len(served) >= 30
    # Its control loop's process, orphaned, stops the robot and ends the run.
    _wait_for(lambda: "run crash: running -> interrupted (agent died during run)" in agent.log())

    restarted = start_agent(data_dir, log_path, AGENT_TOKEN=TOKEN)
    agents.append(restarted)
    with AgentClient(restarted.url, TOKEN) as client:
        run = client.get_run("crash")
        assert run["state"] == "interrupted"
        assert run["reason"] == "agent died during run"
        assert run["ended_at"] is not None
        stored = list(client.iter_samples("crash", 0, limit=11))
        seqs = [sample["seq"] for sample in stored]
        assert seqs == list(range(1, len(stored) + 1))  # once each, no gap
        assert run["sample_count"] == len(stored) == run["last_seq"]
        assert stored[: len(served)] == served  # identical, field for field
        # Nothing is added to an ended run, and the restarted agent holds the robot at rest.
        time.sleep(0.3)
        assert client.get_run("crash")["sample_count"] == len(stored)
        status = client.status()
        assert status["current_run"] is None
        assert status["robot"]["commanded_velocity_mps"] == 0.0


def test_the_real_server_refuses_traversal_and_oversized_bodies(
    tmp_path: Path, agents: list[Agent]
) -> None:
    agent = start_agent(tmp_path / "data", tmp_path / "agent.log", AGENT_TOKEN=TOKEN)
    agents.append(agent)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    # http.client sends the path as written (no dot-segment removal, unlike browsers/urllib3).
    for path in (
        "/api/v1/logs/../../etc/passwd",
        "/api/v1/logs/..%2F..%2Fetc%2Fpasswd",
        "/api/v1/logs/%2e%2e%2f%2e%2e%2fetc%2fpasswd",
        "/api/v1/../../../etc/passwd",
    ):
        connection = http.client.HTTPConnection("127.0.0.1", agent.port, timeout=5)
        connection.request("GET", path, headers=auth)
        response = connection.getresponse()
        body = response.read().decode("utf-8", "replace")
        connection.close()
        assert response.status in (400, 404, 422), (path, response.status)
        assert "root:" not in body
    # A body over the agent's limit is refused before it is read, whatever the endpoint,
    # but a stop: that is never refused for its body (tests/security/test_stop.py).
    control = b'{"velocity_mps": 0.1, "direction": "cw", "ttl_s": 1, "user": "' + b"x" * 200_000
    connection = http.client.HTTPConnection("127.0.0.1", agent.port, timeout=5)
    connection.request(
        "POST",
        "/api/v1/control",
        body=control + b'"}',
        headers={**auth, "Content-Type": "application/json"},
    )
    response = connection.getresponse()
    response.read()
    connection.close()
    assert response.status == 413
    # Over the HTTP server's own buffer too: the same JSON 413, naming the agent's limit. The
    # server answers as soon as it has the headers and closes; requests reads that answer.
    for size in (200_000, 10 * 2**20):
        refused = requests.post(
            f"{agent.url}/api/v1/control",
            data=b'{"user": "' + b"x" * size + b'"}',
            headers={**auth, "Content-Type": "application/json"},
            timeout=10,
        )
        assert refused.status_code == 413, size
        assert refused.headers["Content-Type"] == "application/json"
        assert refused.json() == {
            "error": "request_entity_too_large",
            "detail": f"The body is larger than {MAX_BODY_BYTES} bytes.",
        }
    with AgentClient(agent.url, TOKEN) as client:
        assert client.status()["estop"]["latched"] is False
    # A stop over the server's buffer still stops the robot.
    stopped = requests.post(
        f"{agent.url}/api/v1/stop",
        data=b'{"reason": "' + b"x" * 10 * 2**20 + b'"}',
        headers={**auth, "Content-Type": "application/json"},
        timeout=10,
    )
    assert stopped.status_code == 200, stopped.text
    with AgentClient(agent.url, TOKEN) as client:
        assert client.status()["estop"]["latched"] is True


def test_a_killed_agent_leaves_the_robot_to_stop_by_itself(
    tmp_path: Path, agents: list[Agent]
) -> None:
    """The robot runs in its own process (as on the roof): the agent's death is its silence."""
    from tests.basestation.sim.test_process import inspect

    with sim_robot_process() as robot:
        base_port, robot_port, inspect_port = robot.base_port, robot.robot_port, robot.inspect_port
        agent = start_agent(
            tmp_path / "data", tmp_path / "agent.log", AGENT_TOKEN=TOKEN, AGENT_ROBOT="sim-udp",
            AGENT_SIM_BASE_PORT=str(base_port), AGENT_SIM_ROBOT_PORT=str(robot_port),
        )  # fmt: skip
        agents.append(agent)
        with AgentClient(agent.url, TOKEN) as client:
            segments = [{"velocity_mps": 1.0, "direction": "cw", "duration_s": 60.0}]
            client.put_run("roof", run_body(time.time() + 0.5, window_s=120.0, segments=segments))
            moving = _wait_for(lambda: (s := inspect(inspect_port))["velocity_mps"] >= 0.9 and s)
            agent.process.kill()  # SIGKILL: the robot hears nothing more
            agent.process.wait(10)
        state = _wait_for(lambda: (s := inspect(inspect_port))["velocity_mps"] == 0.0 and s)
        # Stopped by its own dead-man (how soon is `make bench`'s to measure).
        assert state["dead_man"], state
        assert state["track_m"] > moving["track_m"]
        assert robot.process.poll() is None  # it stopped itself; nobody stopped it

        restarted = start_agent(
            tmp_path / "data", tmp_path / "agent.log", AGENT_TOKEN=TOKEN, AGENT_ROBOT="sim-udp",
            AGENT_SIM_BASE_PORT=str(base_port), AGENT_SIM_ROBOT_PORT=str(robot_port),
        )  # fmt: skip
        agents.append(restarted)
        with AgentClient(restarted.url, TOKEN) as client:
            assert client.get_run("roof")["state"] == "interrupted"
