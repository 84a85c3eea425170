"""The control loop in its own process (``python -m basestation`` spawns and supervises it).

- HTTP cannot hold it up: with the agent's HTTP process frozen (SIGSTOP), the loop keeps
  recording a sample every tick into the run store.
- A killed loop process never leaves the robot moving: the robot (its own process, as on
  the roof) stops on its firmware's dead-man; the agent reports the death and starts the
  loop again, which takes up commands (an e-stop reaches the robot through the new one).
"""

from __future__ import annotations

import os
import pickle
import signal
import socket
import sqlite3
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

import pytest

from basestation.client import AgentClient, AgentError
from basestation.loop_process import STALE_AFTER_S, LoopProcess, LoopState
from basestation.tick_rules import AgentSnapshot
from tests.basestation.conftest import TOKEN, run_body
from tests.basestation.processes import Agent, sim_robot_process, start_agent

pytestmark = pytest.mark.integration

T = TypeVar("T")
HZ = 50
# Only bounds a hang: how fast the loop ticks is measured by `make bench`, not here.
HANG_S = 30.0


@pytest.fixture
def agents() -> Iterator[list[Agent]]:
    started: list[Agent] = []
    yield started
    for agent in started:
        if agent.process.poll() is None:
            agent.process.send_signal(signal.SIGCONT)  # a frozen agent cannot clean up
        agent.kill()


def _wait_for(condition: Callable[[], T | None], timeout_s: float = HANG_S) -> T:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError("timed out")


def _last_seq(store_path: Path, run_id: str) -> int:
    """The newest stored sample of the run, read straight from the WAL store."""
    with sqlite3.connect(f"file:{store_path}?mode=ro", uri=True, timeout=5.0) as db:
        row = db.execute("SELECT max(seq) FROM samples WHERE run_id = ?", (run_id,)).fetchone()
    return int(row[0] or 0)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_the_loop_runs_in_its_own_process_and_ticks_on_while_http_is_frozen(
    tmp_path: Path, agents: list[Agent]
) -> None:
    data_dir = tmp_path / "data"
    # The CPU the agent picks by itself (unset: automatic), the last one it may use; named
    # when there is only one, which it would otherwise leave unpinned.
    allowed = sorted(os.sched_getaffinity(0))
    cpu = allowed[-1]
    agent = start_agent(
        data_dir,
        tmp_path / "agent.log",
        AGENT_TOKEN=TOKEN,
        AGENT_CONTROL_HZ=str(HZ),
        AGENT_CONTROL_CPU="" if len(allowed) >= 2 else str(cpu),
    )
    agents.append(agent)
    with AgentClient(agent.url, TOKEN) as client:
        control = client.status()["control"]
        loop_pid = control["pid"]
        assert isinstance(loop_pid, int)
        assert loop_pid != agent.process.pid
        assert _alive(loop_pid)
        assert control["hz"] == HZ
        # The whole loop process (the tick, the request thread, the store writer, the robot
        # link's) keeps to the tick's CPU: a helper elsewhere could hold the GIL up there.
        assert control["cpu"] == cpu
        tids = [int(task.name) for task in Path(f"/proc/{loop_pid}/task").iterdir()]
        assert len(tids) >= 3
        assert {tid: os.sched_getaffinity(tid) for tid in tids} == {tid: {cpu} for tid in tids}
        segments = [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 60.0}]
        client.put_run("frozen", run_body(time.time() + 0.3, window_s=120.0, segments=segments))
        _wait_for(lambda: client.get_run("frozen")["state"] == "running")

    store_path = data_dir / "runs.sqlite3"
    _wait_for(lambda: _last_seq(store_path, "frozen") > 0)
    agent.process.send_signal(signal.SIGSTOP)
    try:
        frozen_at = _last_seq(store_path, "frozen")
        # Two seconds' worth of ticks while nobody in the HTTP process can run at all.
        _wait_for(lambda: _last_seq(store_path, "frozen") >= frozen_at + 2 * HZ)
        assert agent.process.poll() is None
    finally:
        agent.process.send_signal(signal.SIGCONT)
    with AgentClient(agent.url, TOKEN) as client:
        stored = _last_seq(store_path, "frozen")
        # Every stored sample is a tick of that loop (ticks late or skipped on a busy machine
        # are `make bench`'s to count). The agent reports the loop's state as of the last
        # datagram it read: just woken, it catches up on what the loop sent meanwhile.
        status = _wait_for(
            lambda: (status := client.status())["control"]["ticks"] >= stored and status
        )
        assert status["control"]["pid"] == loop_pid
        assert status["control"]["running"]
        assert status["faults"] == []
        # The API's requests reach the loop's process and its answers come back, refusals
        # included: the run holds the robot, so manual drive is refused without force.
        with pytest.raises(AgentError) as refused:
            client.control(user="admin", velocity_mps=0.3, direction="ccw")
        assert refused.value.status == 409
        assert "robot_busy" in str(refused.value.body)
        taken = client.control(user="admin", velocity_mps=0.3, direction="ccw", force=True)
        assert taken["aborted_run"] == "frozen"
        assert client.status()["manual"]["user"] == "admin"
        assert client.get_run("frozen")["state"] == "aborted"


def test_a_killed_loop_process_leaves_the_robot_stopped_and_is_reported_and_started_again(
    tmp_path: Path, agents: list[Agent]
) -> None:
    from tests.basestation.sim.test_process import inspect

    with sim_robot_process() as robot:
        base_port, robot_port, inspect_port = robot.base_port, robot.robot_port, robot.inspect_port
        agent = start_agent(
            tmp_path / "data", tmp_path / "agent.log", AGENT_TOKEN=TOKEN, AGENT_ROBOT="sim-udp",
            AGENT_SIM_BASE_PORT=str(base_port), AGENT_SIM_ROBOT_PORT=str(robot_port),
            AGENT_CONTROL_HZ=str(HZ),
        )  # fmt: skip
        agents.append(agent)
        with AgentClient(agent.url, TOKEN) as client:
            first_pid = client.status()["control"]["pid"]
            segments = [{"velocity_mps": 1.0, "direction": "cw", "duration_s": 60.0}]
            client.put_run("cut", run_body(time.time() + 0.3, window_s=120.0, segments=segments))
            _wait_for(lambda: inspect(inspect_port)["velocity_mps"] >= 0.9)

            os.kill(first_pid, signal.SIGKILL)  # the loop alone: the agent lives on
            # Nobody commands it any more: the firmware's dead-man takes over after 500 ms
            # (the agent starts the loop again only after a second).
            _wait_for(lambda: inspect(inspect_port)["dead_man"])
            _wait_for(lambda: inspect(inspect_port)["velocity_mps"] == 0.0)
            assert agent.process.poll() is None

            # Reported, then running again in a new process that holds the robot.
            restarted = _wait_for(
                lambda: (
                    (c := client.status()["control"])["restarts"] == 1
                    and c["running"]
                    and c["pid"] != first_pid
                    and c
                )
            )
            assert _alive(restarted["pid"])
            assert not _alive(first_pid)
            run = client.get_run("cut")
            assert run["state"] == "interrupted"
            assert "control loop restarted" in run["reason"]
            assert "died" in agent.log()
            # Commands reach the robot through the new loop process.
            client.stop(reason="after the restart")
            _wait_for(lambda: inspect(inspect_port)["e_stop_latched"])


def test_a_burst_of_sigterms_as_the_agent_dies_stops_the_loop_process(
    tmp_path: Path, agents: list[Agent]
) -> None:
    """The agent's death sends the loop SIGTERM (its parent-death signal) just as a stop of
    the process group does: signals arriving while the handler of the one before runs must
    still end the process, not hang it with its loop ticking on."""
    agent = start_agent(tmp_path / "data", tmp_path / "agent.log", AGENT_TOKEN=TOKEN)
    agents.append(agent)
    with AgentClient(agent.url, TOKEN) as client:
        loop_pid = client.status()["control"]["pid"]
    assert isinstance(loop_pid, int)
    agent.process.send_signal(signal.SIGKILL)
    for _ in range(2000):
        try:
            os.kill(loop_pid, signal.SIGTERM)
        except ProcessLookupError:
            break
    _wait_for(lambda: not _alive(loop_pid))


class _Alive:
    def is_alive(self) -> bool:
        return True


def test_a_loop_whose_states_wait_unread_is_running_not_stopped(agent_config) -> None:
    """This process stood still (starved, SIGSTOP) while the loop kept sending: the states
    waiting on the socket are read before the loop is called stopped."""
    loop = LoopProcess(agent_config)
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    with ours, theirs:
        ours.setblocking(False)
        loop._process = _Alive()
        loop._state_sock = ours
        loop._state_at_s = time.monotonic() - 10 * STALE_AFTER_S
        assert not loop.running  # nothing waits: stale is stale

        state = LoopState(
            pid=1, api_version=0, snapshot=AgentSnapshot(ticks=7), estop=None, manual=None,
            ticks=7, late_ticks=0, skipped_ticks=0, tick_errors=0, max_lateness_s=0.0,
            realtime=False, pinned_cpu=None, writer_alive=True, timings=((7, 0.001, 0.002),),
        )  # fmt: skip
        theirs.send(pickle.dumps(state))
        assert loop.running
        assert loop.stats().ticks == 7
