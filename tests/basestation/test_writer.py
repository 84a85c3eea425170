"""The store writer thread: order, batching, refusal, and nothing lost on stop."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from basestation import writer as writer_module
from basestation.program import parse_run_body
from basestation.runtime import AgentRuntime
from basestation.store import RunStore, Sample
from basestation.writer import StoreWriter, WriterFull
from tests.basestation.conftest import RecordingRobot, run_body

T0 = 1_900_000_000.0


def _sample(seq: int) -> Sample:
    return Sample(seq, T0 + seq * 0.05, 0, 0.5, 0.5, "cw", 60.0, 1.0)


@pytest.fixture
def store(tmp_path: Path) -> Iterator[RunStore]:
    store = RunStore(tmp_path / "runs.sqlite3")
    store.stage_run("r", parse_run_body(run_body(T0)), now_s=T0 - 60, admit=lambda _: None)
    store.transition("r", from_states=["staged"], to_state="running", reason="", now_s=T0)
    yield store
    store.close()


def test_it_applies_samples_and_transitions_in_the_order_queued(store: RunStore) -> None:
    refused: list[str] = []
    writer = StoreWriter(store, capacity=1000, on_refused=refused.append)
    writer.start()
    for seq in range(1, 301):
        assert writer.append("r", _sample(seq)) is None
    writer.submit(
        lambda: store.transition(
            "r", from_states=["running"], to_state="completed", reason="done", now_s=T0 + 20
        )
    )
    writer.append("r", _sample(301))  # after the end: refused, never stored
    writer.stop()
    assert [s.seq for s in store.samples_after("r", 0, 1000)] == list(range(1, 301))
    record = store.get_run("r")
    assert record is not None
    assert record.state == "completed"
    assert refused == ["r"]


def test_samples_queued_while_it_writes_go_in_one_transaction(store: RunStore) -> None:
    writer = StoreWriter(store, capacity=1000, on_refused=lambda _: None)
    writer.start()
    entered, release = threading.Event(), threading.Event()

    def slow_operation() -> None:  # a commit that takes a while, as on a loaded SD card
        entered.set()
        release.wait(10)

    writer.submit(slow_operation)
    assert entered.wait(10)
    for seq in range(1, 301):  # 15 s of ticks pile up behind it
        writer.append("r", _sample(seq))
    release.set()
    writer.stop()
    assert [s.seq for s in store.samples_after("r", 0, 1000)] == list(range(1, 301))
    assert writer.batches == 1  # one commit for the backlog, not 300


def test_a_batch_holds_at_most_max_batch_samples(
    store: RunStore, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(writer_module, "MAX_BATCH", 100)
    writer = StoreWriter(store, capacity=1000, on_refused=lambda _: None)
    writer.start()
    entered, release = threading.Event(), threading.Event()
    writer.submit(lambda: (entered.set(), release.wait(10)))
    assert entered.wait(10)
    for seq in range(1, 251):
        writer.append("r", _sample(seq))
    release.set()
    writer.stop()
    assert [s.seq for s in store.samples_after("r", 0, 1000)] == list(range(1, 251))
    assert writer.batches == 3  # 100 + 100 + 50


def test_it_writes_inline_until_started(store: RunStore) -> None:
    writer = StoreWriter(store, capacity=10, on_refused=lambda _: None)
    assert writer.append("r", _sample(1)) is True
    assert writer.submit(lambda: 42) == 42
    assert store.sample_stats("r").count == 1


def test_a_full_queue_refuses_the_sample_instead_of_blocking_the_tick(store: RunStore) -> None:
    writer = StoreWriter(store, capacity=2, on_refused=lambda _: None)
    writer.start()
    entered, release = threading.Event(), threading.Event()

    def slow_operation() -> None:  # a disk that stalls
        entered.set()
        release.wait(10)

    writer.submit(slow_operation)
    assert entered.wait(10)
    writer.append("r", _sample(1))
    writer.append("r", _sample(2))
    with pytest.raises(WriterFull):
        writer.append("r", _sample(3))
    release.set()
    writer.stop()
    assert writer.dropped == 1
    assert [s.seq for s in store.samples_after("r", 0, 10)] == [1, 2]


def test_a_queued_start_is_not_taken_for_a_lost_run(
    runtime: AgentRuntime, robot: RecordingRobot
) -> None:
    # The writer is held up: the tick's start of the run is still queued when the manager
    # re-reads the schedule. It must neither let go of the run nor start it twice.
    writer = runtime.manager.writer
    writer.start()
    entered, release = threading.Event(), threading.Event()

    def stall() -> None:
        entered.set()
        release.wait(10)

    spec = parse_run_body(run_body(T0 + 0.5))
    runtime.store.stage_run("run-1", spec, now_s=T0 - 60, admit=lambda _: None)
    writer.submit(stall)
    assert entered.wait(10)
    for k in range(40):  # 2 s: the run starts at 0.5 s, the schedule is re-read at 1 s
        runtime.manager.tick(T0 + k * 0.05)
        if k == 25:
            runtime.manager.notify_runs_changed()
    assert runtime.manager.snapshot.current_run == "run-1"
    release.set()
    writer.flush()
    samples = runtime.store.samples_after("run-1", 0, 1000)
    assert [s.seq for s in samples] == list(range(1, len(samples) + 1))
    assert len(samples) == 30
