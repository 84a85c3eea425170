"""The control loop: calls the manager's tick at a fixed rate in its own thread.

Deadlines are absolute (``start + k * period`` on the monotonic clock), so a slow tick
delays only itself and the rate never drifts. A tick that wakes more than one period after
its deadline counts as late (its slot was missed), and the loop then skips the missed
slots instead of firing a burst of ticks to catch up: a burst of command frames would only
crowd the radio.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ControlStats:
    hz: float
    running: bool
    ticks: int
    late_ticks: int
    skipped_ticks: int
    tick_errors: int
    max_lateness_s: float


class ControlLoop:
    def __init__(
        self,
        tick: Callable[[float], None],
        *,
        hz: float,
        monotonic: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        self._tick = tick
        self.hz = hz
        self.period_s = 1.0 / hz
        self._monotonic = monotonic
        self._wall_clock = wall_clock
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.ticks = 0
        self.late_ticks = 0
        self.skipped_ticks = 0
        self.tick_errors = 0
        self.max_lateness_s = 0.0

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("control loop already started")
        self._thread = threading.Thread(target=self._run, name="control-loop", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                logger.error("control loop did not stop within %.1f s", timeout_s)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def stats(self) -> ControlStats:
        return ControlStats(
            hz=self.hz,
            running=self.running,
            ticks=self.ticks,
            late_ticks=self.late_ticks,
            skipped_ticks=self.skipped_ticks,
            tick_errors=self.tick_errors,
            max_lateness_s=self.max_lateness_s,
        )

    def _run(self) -> None:
        start_s = self._monotonic()
        k = 0
        while True:
            deadline_s = start_s + k * self.period_s
            delay_s = deadline_s - self._monotonic()
            # Event.wait doubles as the sleep so that stop() takes effect at once.
            if delay_s > 0 and self._stop.wait(delay_s):
                return
            if self._stop.is_set():
                return
            lateness_s = self._monotonic() - deadline_s
            self.max_lateness_s = max(self.max_lateness_s, lateness_s)
            if lateness_s > self.period_s:
                # This tick missed its slot (the previous tick ran long, or the thread was
                # not scheduled): count it once, and move onto the grid slot now current.
                self.late_ticks += 1
                missed = math.floor(lateness_s / self.period_s)
                self.skipped_ticks += missed
                k += missed
            try:
                self._tick(self._wall_clock())
            except Exception:
                # One bad tick must not stop the robot's command stream for good.
                self.tick_errors += 1
                logger.exception("control tick failed")
            self.ticks += 1
            k += 1
