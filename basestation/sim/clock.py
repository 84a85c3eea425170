"""Clocks for the simulator: real (``time.monotonic``) or a fake one that tests move by hand."""

from __future__ import annotations

import threading
from collections.abc import Callable

#: A clock is any zero-argument callable returning seconds (monotonic, any origin).
Clock = Callable[[], float]


class FakeClock:
    """A clock that only moves when told to; calling it returns the current time in seconds.

    ``sleep`` advances it, so a driver written as "poll, then sleep a little" runs unchanged
    against the emulated radio, in zero wall time and deterministically.
    """

    def __init__(self, start_s: float = 0.0) -> None:
        self._now_s = float(start_s)
        self._lock = threading.Lock()

    def __call__(self) -> float:
        return self._now_s

    @property
    def now_s(self) -> float:
        return self._now_s

    def advance(self, dt_s: float) -> float:
        if dt_s < 0:
            raise ValueError(f"a clock cannot go back ({dt_s} s)")
        with self._lock:
            self._now_s += dt_s
            return self._now_s

    def set(self, now_s: float) -> None:
        with self._lock:
            if now_s < self._now_s:
                raise ValueError(f"a clock cannot go back (from {self._now_s} s to {now_s} s)")
            self._now_s = now_s

    def sleep(self, dt_s: float) -> None:
        self.advance(max(0.0, dt_s))
