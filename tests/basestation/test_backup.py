"""``python -m basestation.backup``: an online backup of a running agent's store, restored
into the stopped agent, which then serves every run and sample of the backup (real agent
processes)."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from basestation.backup import BackupError, store_restore
from basestation.client import AgentClient, AgentNotFound
from tests.basestation.conftest import TOKEN, run_body
from tests.basestation.processes import REPO_ROOT, Agent, start_agent


def _wait_for(check: Callable[[], Any], timeout_s: float = 30.0) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError("timed out")


def _command(data_dir: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "basestation.backup", *args, "--data-dir", str(data_dir)],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )


@pytest.fixture
def agents() -> Iterator[list[Agent]]:
    started: list[Agent] = []
    yield started
    for agent in started:
        agent.kill()


def _stop(agent: Agent) -> None:
    """As ``systemctl stop`` does: SIGTERM, and wait for the agent's clean exit."""
    agent.process.terminate()
    assert agent.process.wait(20) == 0, agent.log()


def test_a_backup_taken_while_the_agent_records_restores_into_the_stopped_agent(
    tmp_path: Path, agents: list[Agent]
) -> None:
    data_dir, log_path, backup = tmp_path / "data", tmp_path / "agent.log", tmp_path / "b.db"
    agent = start_agent(data_dir, log_path, AGENT_TOKEN=TOKEN)
    agents.append(agent)
    with AgentClient(agent.url, TOKEN) as client:
        short = [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 1.0}]
        client.put_run("done", run_body(time.time() + 0.3, window_s=2.0, segments=short))
        _wait_for(lambda: client.get_run("done")["state"] == "completed")
        done_samples = list(client.iter_samples("done"))
        long = [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 50.0}]
        client.put_run("live", run_body(time.time() + 0.3, window_s=60.0, segments=long))
        _wait_for(lambda: client.get_run("live")["sample_count"] >= 20)

        made = _command(data_dir, "backup", str(backup))  # the run goes on meanwhile
        assert made.returncode == 0, made.stderr
        assert "backed up 2 runs" in made.stdout
        refused = _command(data_dir, "restore", str(backup))
        assert refused.returncode == 1
        assert "stop it first" in refused.stderr
        client.put_run("later", run_body(time.time() + 3600))  # not in the backup
        _wait_for(lambda: client.get_run("live")["sample_count"] >= 40)
        live_samples = list(client.iter_samples("live"))
    _stop(agent)

    restored = _command(data_dir, "restore", str(backup))
    assert restored.returncode == 0, restored.stderr
    assert len(list(data_dir.glob("runs.sqlite3.replaced-*"))) == 1  # kept, not deleted

    restarted = start_agent(data_dir, log_path, AGENT_TOKEN=TOKEN)
    agents.append(restarted)
    with AgentClient(restarted.url, TOKEN) as client:
        done = client.get_run("done")
        assert done["state"] == "completed"
        assert list(client.iter_samples("done")) == done_samples
        # Running when the backup was taken: interrupted at the restart, samples kept, a
        # consistent prefix of what the agent recorded (each once, no gap).
        live = client.get_run("live")
        assert live["state"] == "interrupted"
        backed_up = list(client.iter_samples("live"))
        assert 20 <= len(backed_up) < len(live_samples)
        assert backed_up == live_samples[: len(backed_up)]
        with pytest.raises(AgentNotFound):
            client.get_run("later")


def test_a_restore_refuses_what_is_not_an_agent_store_and_changes_nothing(tmp_path: Path):
    data_dir = tmp_path / "data"
    data_dir.mkdir()
    store = data_dir / "runs.sqlite3"
    store.write_bytes(b"the current store")
    other = tmp_path / "other.db"
    with sqlite3.connect(other) as conn:
        conn.execute("CREATE TABLE notes (text)")
    conn.close()
    garbage = tmp_path / "garbage.db"
    garbage.write_bytes(b"not a database at all" * 100)
    for source, why in ((other, "not an agent's run store"), (garbage, "not an SQLite")):
        with pytest.raises(BackupError, match=why):
            store_restore(data_dir, source)
    assert store.read_bytes() == b"the current store"
    assert sorted(p.name for p in data_dir.iterdir()) == ["agent.lock", "runs.sqlite3"]
    missing = _command(data_dir, "backup", str(tmp_path / "nowhere" / "b.db"))
    assert missing.returncode == 1
    assert "is not a directory" in missing.stderr
