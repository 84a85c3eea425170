"""The control loop: calls the manager's tick at a fixed rate in its own thread.

Deadlines are absolute (``start + k * period`` on the monotonic clock), so a slow tick
delays only itself and the rate never drifts. A tick that wakes more than one period after
its deadline counts as late (its slot was missed), and the loop then skips the missed
slots instead of firing a burst of ticks to catch up: a burst of command frames would only
crowd the radio.

Each tick's lateness (wake-up minus deadline) and duration go into a ring holding the last
minute of ticks; :meth:`ControlLoop.stats` reads percentiles from it. Writing a slot is all
the loop pays; the sorting is done by whoever asks, at most once per tick.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

logger = logging.getLogger(__name__)


# The percentiles cover the last minute of ticks: long enough for a p99 to mean something
# (1200 ticks at 20 Hz), short enough to show what the loop does now.
STATS_WINDOW_S = 60.0


@dataclass(frozen=True)
class WindowStats:
    """Lateness and duration percentiles over the last ``ticks`` ticks (nearest rank)."""

    ticks: int = 0
    lateness_p50_s: float | None = None
    lateness_p99_s: float | None = None
    lateness_max_s: float | None = None
    duration_p50_s: float | None = None
    duration_p99_s: float | None = None
    duration_max_s: float | None = None


@dataclass(frozen=True)
class ControlStats:
    hz: float
    running: bool
    ticks: int
    late_ticks: int  # ticks that woke more than one period after their deadline
    skipped_ticks: int  # slots that got no tick at all (the missed ticks)
    tick_errors: int
    max_lateness_s: float  # since start
    window: WindowStats = WindowStats()
    window_s: float = STATS_WINDOW_S


@dataclass(frozen=True)
class Slot:
    """Where a tick stands on the grid ``start + k * period`` once it wakes."""

    k: int  # the slot it serves
    lateness_s: float  # its wake-up minus the deadline it waited for
    missed: int  # slots skipped before it (they get no tick)


def slot_deadline(*, start_s: float, period_s: float, k: int) -> float:
    """Slot ``k``'s deadline: computed from the start, never by adding periods (no drift)."""
    return start_s + k * period_s


def tick_slot(*, start_s: float, period_s: float, k: int, woke_s: float) -> Slot:
    """The slot a tick that waited for slot ``k`` and woke at ``woke_s`` serves: ``k`` if it is
    at most one period late; otherwise the slot now current, the missed ones skipped rather
    than made up with a burst."""
    lateness_s = woke_s - slot_deadline(start_s=start_s, period_s=period_s, k=k)
    missed = math.floor(lateness_s / period_s) if lateness_s > period_s else 0
    return Slot(k=k + missed, lateness_s=lateness_s, missed=missed)


def window_of(lateness_ring: list[float], duration_ring: list[float], n: int) -> WindowStats:
    """The percentiles of the first ``n`` ticks of two rings of per-tick figures."""
    lateness = sorted(lateness_ring[:n])
    duration = sorted(duration_ring[:n])
    return WindowStats(
        ticks=n,
        lateness_p50_s=nearest_rank(lateness, 0.50),
        lateness_p99_s=nearest_rank(lateness, 0.99),
        lateness_max_s=lateness[-1] if lateness else None,
        duration_p50_s=nearest_rank(duration, 0.50),
        duration_p99_s=nearest_rank(duration, 0.99),
        duration_max_s=duration[-1] if duration else None,
    )


class ControlLoop:
    def __init__(
        self,
        tick: Callable[[float], None],
        *,
        hz: float,
        monotonic: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
        rt_priority: int = 0,
        urgent: Callable[[float], None] | None = None,
        urgent_at: Callable[[], float | None] | None = None,
        cpu: int | None = None,
        after_tick: Callable[[float, float], None] | None = None,
        wait: Callable[[float], bool] | None = None,
    ) -> None:
        """``rt_priority`` > 0 runs the loop's thread under SCHED_FIFO at that priority
        (needs CAP_SYS_NICE or RLIMIT_RTPRIO, e.g. systemd's LimitRTPRIO=); without the
        right it logs a warning and runs at normal priority. ``cpu`` pins the loop's thread
        to that CPU (where the process may run there; else a warning and no pinning).

        ``after_tick(lateness_s, duration_s)`` runs on this thread after each tick (the
        control-loop process publishes its state with it).

        ``urgent`` runs on this thread, between two ticks, as soon as :meth:`wake` is called:
        an emergency stop goes on the air then, not up to a period later. It also runs at the
        wall-clock instant ``urgent_at()`` names, if that falls between two ticks: a run then
        starts at its start time, not up to a period later. The grid of ticks does not move.

        ``wait(seconds)`` sleeps until then or until woken (True); by default it waits on the
        loop's own event, which :meth:`wake` and :meth:`stop` set. A test passes a simulated
        clock's ``monotonic``, ``wall_clock`` and ``wait`` to check the timing exactly."""
        self._tick = tick
        self._urgent = urgent
        self._urgent_at = urgent_at
        self._served_urgent_at: float | None = None
        self.rt_priority = rt_priority
        self.realtime = False
        self.cpu = cpu
        self.pinned_cpu: int | None = None
        self._after_tick = after_tick
        self.hz = hz
        self.period_s = 1.0 / hz
        self._monotonic = monotonic
        self._wall_clock = wall_clock
        self._stopping = False
        # Set to stop the loop or to ask for an urgent call; the loop's sleep waits on it.
        self._wake = threading.Event()
        self._wait = wait if wait is not None else self._wake.wait
        self._thread: threading.Thread | None = None
        self.ticks = 0
        self.urgent_calls = 0
        self.late_ticks = 0
        self.skipped_ticks = 0
        self.tick_errors = 0
        self.max_lateness_s = 0.0
        self._ring_size = max(1, math.ceil(STATS_WINDOW_S * hz))
        self._lateness_ring = [0.0] * self._ring_size
        self._duration_ring = [0.0] * self._ring_size
        self._window_cache: tuple[int, WindowStats] = (0, WindowStats())

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("control loop already started")
        self._thread = threading.Thread(target=self._run, name="control-loop", daemon=True)
        self._thread.start()

    def wake(self) -> None:
        """Ask for the urgent call now (from any thread)."""
        self._wake.set()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stopping = True
        self._wake.set()
        if self._thread is not None and self._thread is not threading.current_thread():
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
            window=self.window_stats(),
        )

    def window_stats(self) -> WindowStats:
        ticks = self.ticks
        cached_ticks, cached = self._window_cache
        if cached_ticks == ticks:
            return cached
        # Slicing copies the list in one step under the GIL; a slot written meanwhile is
        # either in this copy or in the next.
        stats = window_of(self._lateness_ring, self._duration_ring, min(ticks, self._ring_size))
        self._window_cache = (ticks, stats)
        return stats

    def _become_realtime(self) -> None:
        """Why real-time helps a Python thread: under HTTP load the loop's thread waits
        for the GIL, not for a CPU. When the GIL is dropped, the kernel wakes the waiting
        threads in priority order, and only real-time priority counts for that: the loop
        gets the GIL at the next hand-over instead of competing with every busy thread."""
        if self.rt_priority <= 0:
            return
        try:
            # pid 0 is the calling thread: only this thread becomes real-time.
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.rt_priority))
        except (OSError, AttributeError) as exc:
            logger.warning(
                "control loop stays at normal priority (SCHED_FIFO %d refused: %s); allow "
                "it with LimitRTPRIO= in the systemd unit",
                self.rt_priority,
                exc,
            )
            return
        self.realtime = True

    def _pin(self) -> None:
        """Keep the loop's thread on one CPU: no migration between ticks, a warm cache."""
        if self.cpu is None:
            return
        try:
            # pid 0 is the calling thread here too.
            os.sched_setaffinity(0, {self.cpu})
        except (OSError, AttributeError, ValueError) as exc:
            logger.warning("control loop not pinned to CPU %d (%s)", self.cpu, exc)
            return
        self.pinned_cpu = self.cpu

    def _run(self) -> None:
        self._become_realtime()
        self._pin()
        logger.info(
            "control loop at %g Hz: %s, %s",
            self.hz,
            f"SCHED_FIFO priority {self.rt_priority}" if self.realtime else "normal priority",
            "not pinned" if self.pinned_cpu is None else f"pinned to CPU {self.pinned_cpu}",
        )
        start_s = self._monotonic()
        k = 0
        duration_s = 0.0  # the last tick's work
        last_late_log_s = -math.inf
        while True:
            deadline_s = slot_deadline(start_s=start_s, period_s=self.period_s, k=k)
            while (delay_s := deadline_s - self._monotonic()) > 0:
                timed = self._timed_urgent(deadline_s)
                if timed is not None:
                    delay_s = max(0.0, timed[0] - self._monotonic())
                # Event.wait doubles as the sleep so that stop() and wake() take effect at once.
                if self._wait(delay_s):
                    self._wake.clear()
                    if self._stopping:
                        return
                    self._call_urgent()
                elif timed is not None:
                    self._served_urgent_at = timed[1]
                    self._call_urgent()
            if self._stopping:
                return
            if self._wake.is_set():  # asked for while a tick ran: this tick serves it
                self._wake.clear()
            woke_s = self._monotonic()
            on_grid = tick_slot(start_s=start_s, period_s=self.period_s, k=k, woke_s=woke_s)
            lateness_s = on_grid.lateness_s
            self.max_lateness_s = max(self.max_lateness_s, lateness_s)
            if lateness_s > self.period_s / 2 and woke_s - last_late_log_s >= 1.0:
                # Whether the tick before overran or this thread was held up says where to
                # look (the link, or the machine); at most one line a second.
                last_late_log_s = woke_s
                logger.warning(
                    "control tick %.1f ms late (the tick before took %.1f ms of the %.0f ms "
                    "period)",
                    lateness_s * 1000,
                    duration_s * 1000,
                    self.period_s * 1000,
                )
            if on_grid.missed:
                # This tick missed its slot (the previous tick ran long, or the thread was
                # not scheduled): count it once, and move onto the grid slot now current.
                self.late_ticks += 1
                self.skipped_ticks += on_grid.missed
                k = on_grid.k
            try:
                self._tick(self._wall_clock())
            except Exception:
                # One bad tick must not stop the robot's command stream for good.
                self.tick_errors += 1
                logger.exception("control tick failed")
            slot = self.ticks % self._ring_size
            duration_s = self._monotonic() - woke_s
            self._lateness_ring[slot] = lateness_s
            self._duration_ring[slot] = duration_s
            self.ticks += 1
            k += 1
            if self._after_tick is not None:
                try:
                    self._after_tick(lateness_s, duration_s)
                except Exception:
                    logger.exception("after-tick call failed")

    def _timed_urgent(self, deadline_s: float) -> tuple[float, float] | None:
        """(monotonic, wall-clock) instant of a timed urgent call due before ``deadline_s``."""
        if self._urgent_at is None:
            return None
        at_wall_s = self._urgent_at()
        if at_wall_s is None or at_wall_s == self._served_urgent_at:
            return None  # nothing asked for, or served already
        at_s = at_wall_s - (self._wall_clock() - self._monotonic())
        if at_s >= deadline_s or at_s < self._monotonic() - self.period_s:
            return None  # the next tick serves it, or it is long past and the ticks did
        return at_s, at_wall_s

    def _call_urgent(self) -> None:
        if self._urgent is None:
            return
        try:
            self._urgent(self._wall_clock())
            self.urgent_calls += 1
        except Exception:
            self.tick_errors += 1
            logger.exception("urgent control call failed")


def nearest_rank(ordered: list[float], fraction: float) -> float | None:
    if not ordered:
        return None
    return ordered[max(0, math.ceil(fraction * len(ordered)) - 1)]
