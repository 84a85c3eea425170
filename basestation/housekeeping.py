"""Background upkeep of the run store, off the control loop's thread.

- WAL checkpoints every few seconds, so SQLite's automatic checkpoint (which runs inside
  whichever commit crosses 1000 WAL pages) does not land on a control tick.
- Retention: runs that ended more than ``AGENT_RETENTION_DAYS`` ago are deleted with their
  samples, hourly and once at start.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from basestation.store import PurgeResult, RunStore

logger = logging.getLogger(__name__)

CHECKPOINT_INTERVAL_S = 5.0
PURGE_INTERVAL_S = 3600.0
PURGE_PAUSE_S = 0.02  # between delete batches, for the control loop's commits


def purge_expired(
    store: RunStore, *, retention_s: float | None, now_s: float, pause_s: float = 0.0
) -> PurgeResult:
    """Delete what the retention setting no longer keeps (nothing when it is off).

    "Unread by the portal" is kept simple: the portal collects a run within minutes of its
    end, so a run whose end is within the retention period is never deleted, and neither
    is a staged or running run, whatever its age.
    """
    if retention_s is None:
        return PurgeResult()
    return store.purge_ended_before(now_s - retention_s, pause_s=pause_s)


class Housekeeper:
    def __init__(
        self,
        store: RunStore,
        *,
        retention_s: float | None,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        self.store = store
        self.retention_s = retention_s
        self._wall_clock = wall_clock
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.last_purge: PurgeResult | None = None

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("housekeeper already started")
        self._thread = threading.Thread(target=self._run, name="housekeeping", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)

    def _run(self) -> None:
        next_purge_s = 0.0
        while not self._stop.is_set():
            now_s = time.monotonic()
            try:
                if now_s >= next_purge_s:
                    next_purge_s = now_s + PURGE_INTERVAL_S
                    self.last_purge = purge_expired(
                        self.store,
                        retention_s=self.retention_s,
                        now_s=self._wall_clock(),
                        pause_s=PURGE_PAUSE_S,
                    )
                self.store.checkpoint()
            except Exception:
                # Upkeep failing must not take the agent down; the log says why.
                if self._stop.is_set():
                    return
                logger.exception("housekeeping failed")
            self._stop.wait(CHECKPOINT_INTERVAL_S)
