"""The run store on its own, and what a restart of the agent does to it."""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from basestation.app import create_app
from basestation.config import AgentConfig
from basestation.errors import RunConflict
from basestation.program import parse_run_body
from basestation.runtime import get_runtime
from basestation.store import RunStore, Sample, StoreClosed
from tests.basestation.conftest import TOKEN, run_body

T0 = 1_900_000_000.0


def _sample(seq: int) -> Sample:
    return Sample(
        seq=seq,
        t=T0 + seq * 0.05,
        segment=0,
        commanded_velocity_mps=0.5,
        velocity_mps=0.49,
        direction="cw",
        battery_v=59.8,
        track_m=seq * 0.025,
    )


@pytest.fixture
def store(tmp_path: Path) -> Iterator[RunStore]:
    store = RunStore(tmp_path / "runs.sqlite3")
    yield store
    store.close()


def _stage_running(store: RunStore, run_id: str = "run-1") -> None:
    store.stage_run(run_id, parse_run_body(run_body(T0)), now_s=T0 - 60, admit=lambda _: None)
    assert store.transition(
        run_id, from_states=["staged"], to_state="running", reason="started", now_s=T0
    )


def test_it_uses_wal_and_full_sync(store: RunStore) -> None:
    conn = sqlite3.connect(store.path)
    try:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    finally:
        conn.close()
    assert store._conn().execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL


def test_it_stores_a_tick_batch_and_pages_by_seq(store: RunStore) -> None:
    _stage_running(store)
    assert store.append_samples("run-1", [_sample(1), _sample(2), _sample(3)])
    assert store.append_samples("run-1", [_sample(4)])
    assert [s.seq for s in store.samples_after("run-1", 0, 10)] == [1, 2, 3, 4]
    assert [s.seq for s in store.samples_after("run-1", 2, 1)] == [3]
    assert store.samples_after("run-1", 1, 1)[0] == _sample(2)
    stats = store.sample_stats("run-1")
    assert (stats.count, stats.first_seq, stats.last_seq) == (4, 1, 4)


def test_it_never_stores_a_seq_twice(store: RunStore) -> None:
    _stage_running(store)
    store.append_samples("run-1", [_sample(1), _sample(2)])
    with pytest.raises(sqlite3.IntegrityError):
        store.append_samples("run-1", [_sample(3), _sample(2)])
    # The failed batch left nothing behind: one transaction per batch.
    assert [s.seq for s in store.samples_after("run-1", 0, 10)] == [1, 2]


def test_it_refuses_samples_for_a_run_that_is_not_running(store: RunStore) -> None:
    _stage_running(store)
    store.transition("run-1", from_states=["running"], to_state="aborted", reason="x", now_s=T0 + 1)
    assert not store.append_samples("run-1", [_sample(1)])
    assert store.sample_stats("run-1").count == 0


def test_it_refuses_an_overlap_inside_one_transaction_under_concurrent_puts(
    store: RunStore,
) -> None:
    # Eight threads race to stage eight different runs in the same window: exactly one wins.
    outcomes: list[str] = []
    lock = threading.Lock()
    spec = parse_run_body(run_body(T0))

    def stage(index: int) -> None:
        try:
            store.stage_run(f"run-{index}", spec, now_s=T0 - 60, admit=lambda _: None)
            result = "created"
        except RunConflict as exc:
            result = exc.kind
        with lock:
            outcomes.append(result)

    threads = [threading.Thread(target=stage, args=(i,)) for i in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(outcomes) == ["created"] + ["window_overlaps"] * 7


def test_it_marks_a_run_left_running_as_interrupted_on_restart_and_keeps_its_samples_once(
    tmp_path: Path,
) -> None:
    config = AgentConfig(token=TOKEN, data_dir=tmp_path / "agent", robot="simple")
    first = get_runtime(create_app(config, start_control_loop=False))
    _stage_running(first.store)
    first.store.append_samples("run-1", [_sample(seq) for seq in range(1, 51)])
    # The agent dies: no shutdown, the store is simply dropped.
    first.store.close()

    second = get_runtime(create_app(config, start_control_loop=False))
    try:
        record = second.store.get_run("run-1")
        assert record is not None
        assert record.state == "interrupted"
        assert record.reason == "agent restarted during run"
        assert record.ended_at_s is not None
        samples = second.store.samples_after("run-1", 0, 1000)
        assert [s.seq for s in samples] == list(range(1, 51))
        stats = second.store.sample_stats("run-1")
        assert (stats.count, stats.first_seq, stats.last_seq) == (50, 1, 50)
        # The restarted manager never touches the interrupted run again.
        for k in range(40):
            second.manager.tick(T0 + 3.0 + k * 0.05)
        assert second.store.sample_stats("run-1").count == 50
    finally:
        second.close()

    third = get_runtime(create_app(config, start_control_loop=False))
    try:
        record = third.store.get_run("run-1")
        assert record is not None
        assert record.state == "interrupted"
        assert third.store.sample_stats("run-1").count == 50
    finally:
        third.close()


def _ran(store: RunStore, run_id: str, started_s: float, ended_s: float | None) -> None:
    """A run that moved the robot from ``started_s`` until ``ended_s`` (None: still moving)."""
    spec = parse_run_body(run_body(started_s, owner=run_id))
    store.stage_run(run_id, spec, now_s=started_s - 60, admit=lambda _: None)
    assert store.transition(
        run_id, from_states=["staged"], to_state="running", reason="started", now_s=started_s
    )
    if ended_s is not None:
        assert store.transition(
            run_id, from_states=["running"], to_state="completed", reason="done", now_s=ended_s
        )


def test_usage_is_half_open_at_both_ends_of_the_window(store: RunStore) -> None:
    # The window [T0 + 100, T0 + 200): what ends at its start or starts at its end is not in it.
    start_s, end_s = T0 + 100, T0 + 200
    _ran(store, "ended-at-start", T0 + 80, start_s)
    _ran(store, "inside", T0 + 140, T0 + 145)
    _ran(store, "started-at-end", end_s, None)
    _ran(store, "still-running", T0 + 180, None)
    for user, started_s, until_s in [
        ("ended-at-start", T0 + 90, start_s),
        ("across-start", T0 + 95, T0 + 101),
        ("started-at-end", end_s, end_s + 5),
    ]:
        store.manual_session_open(user=user, started_at_s=started_s, until_s=until_s)

    entries = store.usage_between(start_s, end_s)
    assert [(e.kind, e.user) for e in entries] == [
        ("manual", "across-start"),
        ("run", "inside"),
        ("run", "still-running"),
    ]
    # What touches the window's ends belongs to the window on the other side.
    assert {e.user for e in store.usage_between(start_s - 100, start_s)} == {
        "ended-at-start",
        "across-start",
    }
    assert {e.user for e in store.usage_between(end_s, end_s + 100)} == {
        "started-at-end",
        "still-running",
    }


def test_a_close_leaves_a_statement_another_thread_is_stepping_to_that_thread(
    store: RunStore,
) -> None:
    """Closing a connection under a thread mid-statement frees what that thread still uses
    (the agent died of a segmentation fault once, closed at shutdown under an HTTP thread's
    query): the thread finishes its statement and meets ``StoreClosed`` at its next call."""
    stepped, closed = threading.Event(), threading.Event()
    rows: list[int] = []
    outcome: list[BaseException] = []

    def read() -> None:
        try:
            # Any of the store's reads, held between two steps of its statement.
            cursor = store._conn().execute(
                "WITH RECURSIVE n(x) AS (SELECT 1 UNION ALL SELECT x + 1 FROM n WHERE x < 100)"
                " SELECT x FROM n"
            )
            for (x,) in cursor:
                rows.append(x)
                if x == 1:
                    stepped.set()
                    closed.wait(10.0)
            store.get_run("run-1")
        except BaseException as error:  # the test reads which it was
            outcome.append(error)

    reader = threading.Thread(target=read)
    reader.start()
    assert stepped.wait(10.0)
    store.close()
    closed.set()
    reader.join(10.0)
    assert rows == list(range(1, 101))  # the statement ran to its end
    assert [type(error) for error in outcome] == [StoreClosed]
    with pytest.raises(StoreClosed):
        store.get_run("run-1")
