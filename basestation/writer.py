"""The store writer: the control loop's writes to SQLite, done in order on their own thread.

Why: a tick that commits a sample waits for ``fsync`` (fine, the GIL is released) and then
must win the GIL back after every SQLite call. Under HTTP load, with request threads busy in
Python, each of those hand-overs can cost a switch interval, and a tick with a dozen of
them overran its 50 ms period (measured: p99 tick work 125 ms with 50 clients). With the
writes here, a tick only computes, exchanges one frame with the robot and queues.

What stays true:

- A sample is visible to readers only once its transaction has committed with
  ``synchronous=FULL``: whatever the API has served survives a kill -9, as before.
- Order: samples and run transitions are applied in the order the tick queued them, so a
  run is never ``completed`` before its last sample is stored (the portal relies on that:
  once it sees the end state, one more pull gets every sample).
- Bounded: the queue holds a minute of ticks. If the disk stalls that long, a sample that
  does not fit is dropped and its seq is spent: the portal sees the gap and reports it.

Until :meth:`StoreWriter.start` is called the writer applies everything at once on the
caller's thread (tests drive the manager tick by tick and read the store straight after).
"""

from __future__ import annotations

import logging
import queue
import sqlite3
import threading
from collections.abc import Callable
from typing import Any

from basestation.store import RunStore, Sample

logger = logging.getLogger(__name__)

MAX_BATCH = 500  # samples per transaction when the writer has fallen behind


class WriterFull(Exception):
    """The queue is full: the sample was not stored (its seq is spent)."""


class _Stop:
    pass


_STOP = _Stop()


class StoreWriter:
    def __init__(
        self,
        store: RunStore,
        *,
        capacity: int,
        on_refused: Callable[[str], None],
    ) -> None:
        """``on_refused(run_id)`` is called (on the writer's thread) when samples were
        refused because the run is no longer running: someone ended it meanwhile."""
        self.store = store
        self.capacity = capacity
        self._on_refused = on_refused
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=capacity)
        self._thread: threading.Thread | None = None
        self.batches = 0
        self.dropped = 0

    @property
    def threaded(self) -> bool:
        return self._thread is not None

    @property
    def alive(self) -> bool:
        """False only when the thread was started and has died (samples are not stored)."""
        return self._thread is None or self._thread.is_alive()

    @property
    def backlog(self) -> int:
        return self._queue.qsize()

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("store writer already started")
        self._thread = threading.Thread(target=self._run, name="store-writer", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 10.0) -> None:
        """Apply everything queued, then stop."""
        thread = self._thread
        if thread is None:
            return
        self._queue.put(_STOP)
        thread.join(timeout_s)
        if thread.is_alive():
            logger.error("store writer did not finish within %.1f s", timeout_s)
        self._thread = None

    def flush(self) -> None:
        """Wait until everything queued so far is applied."""
        if self._thread is not None:
            self._queue.join()

    def append(self, run_id: str, sample: Sample) -> bool | None:
        """Store a sample of a running run. Inline: True, or False when the run is not
        running. Threaded: None (queued); raises :class:`WriterFull`."""
        if self._thread is None:
            return self.store.append_samples(run_id, [sample])
        try:
            self._queue.put_nowait((run_id, sample))
        except queue.Full:
            self.dropped += 1
            raise WriterFull(f"store writer queue full ({self.capacity})") from None
        return None

    def submit(self, operation: Callable[[], object]) -> object | None:
        """Apply a store operation after everything queued before it. Inline: its result.
        Threaded: None; it is queued (waiting for room: it must not be lost)."""
        if self._thread is None:
            return operation()
        self._queue.put(operation)
        return None

    # -- the writer thread ------------------------------------------------------------------------

    def _run(self) -> None:
        pending: Any = None
        while True:
            item = pending if pending is not None else self._queue.get()
            pending = None
            if isinstance(item, _Stop):
                self._queue.task_done()
                return
            if callable(item):
                self._apply(item)
                self._queue.task_done()
                continue
            run_id, sample = item
            batch = [sample]
            # Whatever queued up meanwhile for the same run goes in the same transaction.
            while len(batch) < MAX_BATCH:
                try:
                    following = self._queue.get_nowait()
                except queue.Empty:
                    break
                if isinstance(following, tuple) and following[0] == run_id:
                    batch.append(following[1])
                else:
                    pending = following
                    break
            self._write(run_id, batch)
            for _ in batch:
                self._queue.task_done()

    def _write(self, run_id: str, batch: list[Sample]) -> None:
        try:
            stored = self.store.append_samples(run_id, batch)
        except sqlite3.Error:
            # The seqs are spent: a gap tells the portal exactly what is missing.
            logger.exception(
                "run %s: samples %d-%d not stored", run_id, batch[0].seq, batch[-1].seq
            )
            return
        self.batches += 1
        if not stored:
            self._on_refused(run_id)

    def _apply(self, operation: Callable[[], object]) -> None:
        try:
            operation()
        except Exception:
            logger.exception("store writer: operation failed")
