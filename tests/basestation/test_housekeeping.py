"""The run store's upkeep: retention, the disk-space guard, WAL checkpoints."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import pytest
from flask.testing import FlaskClient

from basestation.app import create_app
from basestation.config import AgentConfig
from basestation.housekeeping import Housekeeper, purge_expired
from basestation.program import parse_run_body
from basestation.runtime import AgentRuntime, get_runtime
from basestation.services import BYTES_PER_SAMPLE, MB
from basestation.store import Sample
from basestation.system import DiskSpace
from tests.basestation.conftest import RecordingRobot, run_body

DAY_S = 86_400.0
T0 = 1_900_000_000.0


def _run_with_samples(
    runtime: AgentRuntime, run_id: str, start_s: float, *, samples: int, end_state: str | None
) -> None:
    store = runtime.store
    spec = parse_run_body(run_body(start_s))
    store.stage_run(run_id, spec, now_s=start_s - 60, admit=lambda _: None)
    store.transition(run_id, from_states=["staged"], to_state="running", reason="", now_s=start_s)
    batch = [
        Sample(
            seq=seq,
            t=start_s + seq * 0.05,
            segment=0,
            commanded_velocity_mps=0.5,
            velocity_mps=0.5,
            direction="cw",
            battery_v=60.0,
            track_m=0.0,
        )
        for seq in range(1, samples + 1)
    ]
    assert store.append_samples(run_id, batch)
    if end_state is not None:
        store.transition(
            run_id, from_states=["running"], to_state=end_state, reason="", now_s=start_s + 9
        )


def test_retention_deletes_old_ended_runs_with_their_samples_and_keeps_the_rest(
    runtime: AgentRuntime,
) -> None:
    old_s = T0 - 100 * DAY_S
    _run_with_samples(runtime, "old-completed", old_s, samples=5_000, end_state="completed")
    _run_with_samples(runtime, "old-aborted", old_s + 20, samples=10, end_state="aborted")
    _run_with_samples(runtime, "old-running", old_s + 40, samples=10, end_state=None)
    _run_with_samples(runtime, "recent", T0 - 10 * DAY_S, samples=10, end_state="completed")
    runtime.store.manual_session_open(user="admin", started_at_s=old_s, until_s=old_s + 1)
    runtime.store.manual_session_open(user="admin", started_at_s=T0 - 1, until_s=T0)

    result = purge_expired(runtime.store, retention_s=90 * DAY_S, now_s=T0)

    assert (result.runs, result.samples, result.manual_sessions) == (2, 5_010, 1)
    remaining = {record.id: stats.count for record, stats in runtime.store.list_runs()}
    # A running run is never deleted, however old; an ended one within retention stays.
    assert remaining == {"old-running": 10, "recent": 10}
    assert len(runtime.store.usage_between(T0 - 200 * DAY_S, T0 + 1)) == 3  # 2 runs, 1 session


def test_retention_zero_keeps_everything(runtime: AgentRuntime) -> None:
    _run_with_samples(runtime, "old", T0 - 1000 * DAY_S, samples=3, end_state="completed")
    assert purge_expired(runtime.store, retention_s=None, now_s=T0).runs == 0
    assert runtime.store.get_run("old") is not None


def test_retention_deletes_in_small_batches(runtime: AgentRuntime) -> None:
    _run_with_samples(runtime, "old", T0 - 100 * DAY_S, samples=250, end_state="completed")
    result = runtime.store.purge_ended_before(T0, batch_rows=100)
    assert (result.runs, result.samples) == (1, 250)


def test_the_housekeeper_purges_at_start_and_checkpoints(
    agent_config: AgentConfig, runtime: AgentRuntime
) -> None:
    now_s = time.time()
    _run_with_samples(runtime, "old", now_s - 100 * DAY_S, samples=20, end_state="completed")
    keeper = Housekeeper(runtime.store, retention_s=90 * DAY_S)
    keeper.start()
    deadline_s = time.monotonic() + 10.0
    while keeper.last_purge is None and time.monotonic() < deadline_s:
        time.sleep(0.01)
    keeper.stop()
    assert keeper.last_purge is not None
    assert keeper.last_purge.runs == 1
    assert runtime.store.get_run("old") is None


# -- the disk-space guard ------------------------------------------------------------------------


def _free(free_bytes: float) -> Callable[[Path], DiskSpace]:
    return lambda _path: DiskSpace(free_bytes=int(free_bytes), total_bytes=10**12)


def test_a_new_run_is_refused_before_the_disk_fills(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime, soon: float
) -> None:
    # A 10 s window at 20 Hz is 200 samples; the agent keeps 200 MB free by default.
    run_bytes = 10 * 20 * BYTES_PER_SAMPLE
    runtime.disk_probe = _free(200 * MB + run_bytes - 1)
    response = client.put("/api/v1/runs/run-1", json=run_body(soon), headers=auth)
    assert response.status_code == 507
    body = response.json
    assert body is not None
    assert body["error"] == "insufficient_storage"
    assert "AGENT_MIN_FREE_DISK_MB" in body["detail"]
    assert runtime.store.list_runs() == []

    runtime.disk_probe = _free(200 * MB + run_bytes + 1)
    assert client.put("/api/v1/runs/run-1", json=run_body(soon), headers=auth).status_code == 201


def test_the_disk_guard_counts_the_runs_already_staged(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime, soon: float
) -> None:
    run_bytes = 10 * 20 * BYTES_PER_SAMPLE
    runtime.disk_probe = _free(200 * MB + 1.5 * run_bytes)
    assert client.put("/api/v1/runs/a", json=run_body(soon), headers=auth).status_code == 201
    response = client.put("/api/v1/runs/b", json=run_body(soon + 60), headers=auth)
    assert response.status_code == 507


def test_the_disk_guard_does_not_refuse_a_repeated_put(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime, soon: float
) -> None:
    assert client.put("/api/v1/runs/a", json=run_body(soon), headers=auth).status_code == 201
    runtime.disk_probe = _free(0)
    assert client.put("/api/v1/runs/a", json=run_body(soon), headers=auth).status_code == 200


def test_min_free_disk_zero_switches_the_guard_off(
    agent_config: AgentConfig, robot: RecordingRobot, auth: dict[str, str], soon: float
) -> None:
    app = create_app(
        replace(agent_config, min_free_disk_mb=0.0), start_control_loop=False, robot=robot
    )
    try:
        get_runtime(app).disk_probe = _free(0)
        response = app.test_client().put("/api/v1/runs/a", json=run_body(soon), headers=auth)
        assert response.status_code == 201
    finally:
        get_runtime(app).close()


def test_status_reports_free_disk(client: FlaskClient, auth: dict[str, str]) -> None:
    host = client.get("/api/v1/status", headers=auth).json["host"]  # type: ignore[index]
    assert 0 < host["disk_free_bytes"] <= host["disk_total_bytes"]


@pytest.mark.parametrize("samples", [72_000])
def test_bytes_per_sample_covers_what_a_sample_really_costs(
    runtime: AgentRuntime, samples: int
) -> None:
    # The guard's estimate must not be optimistic: store an hour at 20 Hz and measure.
    before = runtime.store.path.stat().st_size
    _run_with_samples(runtime, "hour", T0, samples=samples, end_state="completed")
    runtime.store.checkpoint()
    grown = runtime.store.path.stat().st_size - before
    assert grown / samples < BYTES_PER_SAMPLE
