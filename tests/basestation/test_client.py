"""AgentClient against the agent app served over real HTTP in a thread."""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from typing import Any

import pytest
from flask import Flask
from werkzeug.serving import make_server

from basestation.client import (
    AgentClient,
    AgentConflict,
    AgentError,
    AgentNotFound,
    AgentRejected,
    AgentUnauthorized,
)
from basestation.runtime import AgentRuntime
from tests.basestation.conftest import TOKEN, run_body

Drive = Callable[[float, float], float]


@pytest.fixture
def base_url(app: Flask) -> Iterator[str]:
    server = make_server("127.0.0.1", 0, app, threaded=True)
    thread = threading.Thread(target=server.serve_forever, args=(0.05,), daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_port}"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


@pytest.fixture
def agent(base_url: str) -> Iterator[AgentClient]:
    with AgentClient(base_url, TOKEN, timeout_s=5.0) as client:
        yield client


def test_it_stages_and_reads_a_run(agent: AgentClient, soon: float) -> None:
    run = agent.put_run("run-1", run_body(soon))
    assert run["state"] == "staged"
    assert agent.put_run("run-1", run_body(soon)) == run
    assert agent.get_run("run-1") == run
    assert [r["id"] for r in agent.list_runs()] == ["run-1"]
    assert agent.list_runs(state="completed") == []
    status = agent.status()
    assert status["resource"] == "mobile-1"
    assert agent.healthz() == {"ok": True}


def test_it_raises_a_non_retryable_conflict_for_a_different_body(
    agent: AgentClient, soon: float
) -> None:
    agent.put_run("run-1", run_body(soon))
    with pytest.raises(AgentConflict) as caught:
        agent.put_run("run-1", run_body(soon, title="other"))
    assert caught.value.status == 409
    assert caught.value.retryable is False
    assert caught.value.kind == "body_differs"


def test_it_raises_rejected_with_the_field_errors(agent: AgentClient, soon: float) -> None:
    body: dict[str, Any] = run_body(soon)
    body["segments"][0]["direction"] = "up"
    with pytest.raises(AgentRejected) as caught:
        agent.put_run("run-1", body)
    assert caught.value.status == 422
    assert caught.value.retryable is False
    assert caught.value.fields == {"segments[0].direction": ["must be 'cw' or 'ccw'"]}


def test_it_raises_not_found_and_unauthorized(base_url: str, agent: AgentClient) -> None:
    with pytest.raises(AgentNotFound):
        agent.get_run("missing")
    with (
        AgentClient(base_url, "wrong-token") as intruder,
        pytest.raises(AgentUnauthorized) as caught,
    ):
        intruder.status()
    assert caught.value.status == 401
    assert caught.value.retryable is False


def test_it_cancels_and_then_conflicts_on_a_second_delete(agent: AgentClient, soon: float) -> None:
    agent.put_run("run-1", run_body(soon))
    assert agent.delete_run("run-1")["state"] == "cancelled"
    with pytest.raises(AgentConflict) as caught:
        agent.delete_run("run-1")
    assert caught.value.kind == "already_ended"


def test_it_iterates_every_sample_across_pages(
    agent: AgentClient, drive: Drive, soon: float
) -> None:
    agent.put_run("run-1", run_body(soon))
    drive(soon, soon + 3.0)  # 60 samples
    assert [s["seq"] for s in agent.iter_samples("run-1", 0, limit=7)] == list(range(1, 61))
    assert [s["seq"] for s in agent.iter_samples("run-1", 55, limit=7)] == list(range(56, 61))
    page = agent.samples("run-1", after_seq=10, limit=5)
    assert (page["last_seq"], page["more"]) == (15, True)


def test_it_marks_server_errors_retryable(agent: AgentClient, runtime: AgentRuntime) -> None:
    runtime.store.close()
    with pytest.raises(AgentError) as caught:
        agent.list_runs()
    assert caught.value.status == 500
    assert caught.value.retryable is True


def test_it_marks_a_refused_connection_retryable() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with (
        AgentClient(f"http://127.0.0.1:{port}", TOKEN, timeout_s=1.0) as client,
        pytest.raises(AgentError) as caught,
    ):
        client.status()
    assert caught.value.retryable is True
    assert caught.value.status is None


def test_it_marks_a_timeout_retryable() -> None:
    # A listening socket that never answers: the connection opens, the reply never comes.
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(1)
        port = silent.getsockname()[1]
        with (
            AgentClient(f"http://127.0.0.1:{port}", TOKEN, timeout_s=0.2) as client,
            pytest.raises(AgentError) as caught,
        ):
            client.status()
    assert caught.value.retryable is True
    assert caught.value.status is None


def test_it_drives_stops_and_reads_the_log_and_the_battery(agent: AgentClient) -> None:
    day_before = datetime.now(UTC).date()
    answer = agent.control(user="admin", velocity_mps=0.2, direction="ccw", ttl_s=2.0)
    assert answer["manual"]["direction"] == "ccw"
    assert agent.control(user="admin", velocity_mps=0, direction="cw")["manual"] is None
    stopped = agent.stop(user="admin", reason="test")
    assert stopped["estop"]["reason"] == "test (by admin)"
    with pytest.raises(AgentConflict) as refused:
        agent.control(user="admin", velocity_mps=0.2, direction="cw")
    assert refused.value.kind == "estop_latched"
    assert refused.value.retryable is False
    assert agent.release_stop(user="admin")["released"] is True
    # The day log is by date: if midnight passed meanwhile, the entries are in either day.
    days = sorted({day_before, datetime.now(UTC).date()})
    entries = [e for day in days for e in agent.day_log(day)["entries"]]
    assert [(e["user"], e["kind"]) for e in entries] == [("admin", "manual")]
    assert set(agent.battery()) >= {"filtered_v", "raw_v"}
