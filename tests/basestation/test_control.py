"""The control loop: rate, absolute deadlines, late and skipped ticks, urgent calls.

The timing is checked on a simulated clock: the loop's ``monotonic``, ``wall_clock`` and
``wait`` are a :class:`SimClock`, whose time moves only when the loop waits or a tick works,
so every tick's instant is known exactly and a busy test machine changes nothing. The loop
still runs on its own thread; a few tests at the end check the real thread and clock.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable

import pytest
from hypothesis import given
from hypothesis import strategies as st

from basestation.control import ControlLoop, slot_deadline, tick_slot

WALL_OFFSET_S = 1_900_000_000.0
START_S = 1000.0


class SimClock:
    """Monotonic and wall-clock time that advance only when the loop waits or a tick
    spends time. ``oversleep_s(n)`` is how much later than asked the n-th wait returns (a
    busy scheduler); ``wakes`` are monotonic instants at which a wait is woken (``wake()``)."""

    def __init__(
        self,
        *,
        oversleep_s: Callable[[int], float] = lambda n: 0.0,
        wakes: list[float] | None = None,
    ) -> None:
        self.now_s = START_S
        self.waits = 0
        self._oversleep_s = oversleep_s
        self._wakes = sorted(wakes or [])

    def monotonic(self) -> float:
        return self.now_s

    def wall_clock(self) -> float:
        return self.now_s + WALL_OFFSET_S

    def wait(self, timeout_s: float) -> bool:
        self.waits += 1
        until_s = self.now_s + timeout_s
        if self._wakes and self._wakes[0] <= until_s:
            self.now_s = max(self.now_s, self._wakes.pop(0))
            return True
        self.now_s = until_s + self._oversleep_s(self.waits)
        return False

    def spend(self, seconds: float) -> None:
        self.now_s += seconds


def run_ticks(
    clock: SimClock,
    n: int,
    *,
    hz: float,
    work_s: Callable[[int], float] = lambda i: 0.0,
    fail: Callable[[int], bool] = lambda i: False,
    urgent: Callable[[float], None] | None = None,
    urgent_at: Callable[[], float | None] | None = None,
) -> tuple[ControlLoop, list[float]]:
    """Run a loop on ``clock`` for ``n`` ticks; the monotonic instant each tick began at.
    Tick ``i`` works ``work_s(i)`` seconds, and raises if ``fail(i)``."""
    stamps: list[float] = []
    done = threading.Event()
    loop: ControlLoop

    def tick(now_s: float) -> None:
        assert now_s == clock.wall_clock()  # the tick is given the wall clock
        i = len(stamps)
        stamps.append(clock.monotonic())
        clock.spend(work_s(i))
        if len(stamps) == n:
            loop.stop()  # from the loop's own thread: it ends after this tick
            done.set()
        if fail(i):
            raise RuntimeError("radio hiccup")

    loop = ControlLoop(
        tick,
        hz=hz,
        monotonic=clock.monotonic,
        wall_clock=clock.wall_clock,
        wait=clock.wait,
        urgent=urgent,
        urgent_at=urgent_at,
    )
    loop.start()
    assert done.wait(60), f"{len(stamps)} of {n} ticks"
    loop.stop()
    assert not loop.running
    return loop, stamps


def test_it_ticks_on_absolute_deadlines_without_drift() -> None:
    # Every wait returns 1 ms late and every tick works 3 ms: a loop that counted its period
    # from the last wake-up or the end of the last tick would be 100 or 400 ms off by now.
    clock = SimClock(oversleep_s=lambda n: 0.001)
    loop, stamps = run_ticks(clock, 100, hz=50.0, work_s=lambda i: 0.003)
    assert loop.ticks == 100
    assert (loop.late_ticks, loop.skipped_ticks, loop.tick_errors) == (0, 0, 0)
    # The first tick is at the start; each later one a wait's 1 ms after its own deadline.
    assert stamps[0] == START_S
    for k, stamp in enumerate(stamps[1:], start=1):
        assert stamp == pytest.approx(START_S + k * 0.02 + 0.001, abs=1e-9)
    assert loop.max_lateness_s == pytest.approx(0.001, abs=1e-9)


PERIOD_S = 1 / 32  # exact in binary: the expected instants below are exact too


def test_a_slow_tick_is_late_its_missed_slots_are_skipped_and_the_grid_holds() -> None:
    # Tick 2 (slot 2) works 4.5 periods and ends at 6.5: slots 3, 4 and 5 are lost, the next
    # tick serves slot 6 half a period late, and the one after is on time at slot 7.
    clock = SimClock()
    loop, stamps = run_ticks(clock, 8, hz=32.0, work_s=lambda i: 4.5 * PERIOD_S if i == 2 else 0.0)
    slots = [(stamp - START_S) / PERIOD_S for stamp in stamps]
    assert slots == [0, 1, 2, 6.5, 7, 8, 9, 10]
    assert (loop.late_ticks, loop.skipped_ticks) == (1, 3)
    assert loop.max_lateness_s == 3.5 * PERIOD_S  # waited for slot 3, woke at 6.5
    # Every slot is accounted for once: ticked or skipped.
    assert loop.ticks + loop.skipped_ticks == 11


def test_a_tick_up_to_one_period_late_keeps_its_slot() -> None:
    # Tick 1 works two periods: slot 2's tick wakes exactly one period late, still serves
    # slot 2, and slot 3's follows at once; no slot is skipped and none is late.
    clock = SimClock()
    loop, stamps = run_ticks(clock, 5, hz=32.0, work_s=lambda i: 2 * PERIOD_S if i == 1 else 0.0)
    assert [(s - START_S) / PERIOD_S for s in stamps] == [0, 1, 3, 3, 4]
    assert (loop.late_ticks, loop.skipped_ticks) == (0, 0)


def test_a_late_tick_is_logged_with_what_the_tick_before_took(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # Tick 1 overran (works 1.75 periods): tick 2 wakes 0.75 of a period late and says so,
    # naming the 1.75 periods the tick before took; tick 5's wait returned 0.6 of a period
    # late with nothing before it slow (the thread was held up), but that is within the
    # same second, so one line is all.
    clock = SimClock(oversleep_s=lambda n: 0.6 * PERIOD_S if n == 4 else 0.0)
    with caplog.at_level("WARNING", logger="basestation.control"):
        run_ticks(clock, 8, hz=32.0, work_s=lambda i: 1.75 * PERIOD_S if i == 1 else 0.0)
    late = [r.getMessage() for r in caplog.records if "late" in r.getMessage()]
    period_ms = PERIOD_S * 1000
    assert late == [
        f"control tick {0.75 * period_ms:.1f} ms late (the tick before took "
        f"{1.75 * period_ms:.1f} ms of the {period_ms:.0f} ms period)"
    ]


def test_it_survives_a_failing_tick() -> None:
    clock = SimClock()
    loop, stamps = run_ticks(clock, 10, hz=32.0, fail=lambda i: i == 1)
    assert loop.tick_errors == 1
    assert loop.ticks == 10
    assert [(s - START_S) / PERIOD_S for s in stamps] == list(range(10))


def test_it_reports_lateness_and_duration_percentiles_over_its_window() -> None:
    # 100 ticks: waits 1 to 100 µs late in turn, ticks working 2 ms.
    clock = SimClock(oversleep_s=lambda n: 1e-6 * (1 + (n - 1) % 100))
    loop = ControlLoop(lambda now_s: None, hz=100.0)
    assert loop.stats().window.ticks == 0
    assert loop.stats().window.lateness_p99_s is None
    loop, _ = run_ticks(clock, 101, hz=100.0, work_s=lambda i: 0.002)
    stats = loop.stats()
    window = stats.window
    assert window.ticks == stats.ticks == 101
    # The first tick is on time; the others are 1..100 µs late, one each.
    assert window.lateness_p50_s == pytest.approx(50e-6, abs=1e-9)
    assert window.lateness_p99_s == pytest.approx(99e-6, abs=1e-9)
    assert window.lateness_max_s == pytest.approx(100e-6, abs=1e-9)
    assert window.duration_p50_s == window.duration_max_s == pytest.approx(0.002, abs=1e-9)
    assert stats.window_s == 60.0


def test_its_window_holds_the_last_minute_of_ticks_only() -> None:
    # At 200 Hz the window is 12 000 ticks. The first 500 ticks are each 3 ms late; the last
    # 12 000 are on time, so the window's maximum no longer sees the early lateness.
    clock = SimClock(oversleep_s=lambda n: 0.003 if n <= 500 else 0.0)
    loop, _ = run_ticks(clock, 12_501, hz=200.0)
    stats = loop.stats()
    assert stats.ticks == 12_501
    assert stats.window.ticks == 12_000
    assert stats.max_lateness_s == pytest.approx(0.003, abs=1e-9)
    assert stats.window.lateness_max_s == 0.0


def test_a_wake_runs_the_urgent_call_between_ticks_without_moving_the_grid() -> None:
    urgent: list[float] = []
    clock = SimClock(wakes=[START_S + 0.2])  # between the ticks at 0 and 0.5 s
    loop, stamps = run_ticks(clock, 3, hz=2.0, urgent=urgent.append)
    assert urgent == [START_S + 0.2 + WALL_OFFSET_S]
    assert loop.urgent_calls == 1
    assert stamps == [START_S, START_S + 0.5, START_S + 1.0]


def test_it_calls_urgent_once_at_the_instant_urgent_at_names_between_ticks() -> None:
    urgent: list[float] = []
    at_s = START_S + 0.2 + WALL_OFFSET_S  # still asked for after it was served
    clock = SimClock()
    _, stamps = run_ticks(clock, 3, hz=2.0, urgent=urgent.append, urgent_at=lambda: at_s)
    assert urgent == [at_s]
    assert stamps == [START_S, START_S + 0.5, START_S + 1.0]


@given(
    start_s=st.floats(0, 1e6),
    hz=st.sampled_from([10.0, 20.0, 50.0, 100.0]),
    k=st.integers(0, 10**6),
    late_periods=st.floats(0, 50),
)
def test_a_late_tick_serves_the_slot_now_current(
    start_s: float, hz: float, k: int, late_periods: float
) -> None:
    period_s = 1 / hz
    deadline_s = slot_deadline(start_s=start_s, period_s=period_s, k=k)
    woke_s = deadline_s + late_periods * period_s
    slot = tick_slot(start_s=start_s, period_s=period_s, k=k, woke_s=woke_s)
    assert slot.k == k + slot.missed
    assert slot.lateness_s == pytest.approx(woke_s - deadline_s)
    served_s = slot_deadline(start_s=start_s, period_s=period_s, k=slot.k)
    tolerance_s = 1e-6
    if slot.lateness_s <= period_s:
        assert slot.missed == 0  # on time or late within its period: its own slot
    else:
        # On the grid again: the served slot began at most one period before the wake-up.
        assert served_s - tolerance_s <= woke_s <= served_s + period_s + tolerance_s


# -- the real thread and clock ------------------------------------------------------------------


def _until(condition: Callable[[], bool], timeout_s: float = 10.0) -> None:
    deadline_s = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline_s, "timed out"
        time.sleep(0.005)


def test_the_thread_ticks_with_the_wall_clock_until_stopped() -> None:
    seen: list[float] = []
    loop = ControlLoop(seen.append, hz=100.0)
    loop.start()
    try:
        _until(lambda: len(seen) >= 3)
    finally:
        loop.stop()
    assert not loop.running
    assert abs(seen[-1] - time.time()) < 5.0
    stopped_at = len(seen)
    assert loop.ticks == stopped_at  # nothing after stop


def test_a_wake_from_another_thread_runs_the_urgent_call_at_once() -> None:
    urgent = threading.Event()
    first_tick = threading.Event()
    loop = ControlLoop(
        lambda now_s: first_tick.set(),
        hz=0.1,  # ten seconds between ticks: only the wake can call urgent in time
        urgent=lambda now_s: urgent.set(),
    )
    loop.start()
    try:
        assert first_tick.wait(10)
        loop.wake()
        assert urgent.wait(5)
        assert loop.urgent_calls == 1
        assert loop.ticks == 1
    finally:
        loop.stop()


def test_stop_is_not_taken_for_a_wake() -> None:
    urgent: list[float] = []
    first_tick = threading.Event()
    loop = ControlLoop(lambda now_s: first_tick.set(), hz=2.0, urgent=urgent.append)
    loop.start()
    assert first_tick.wait(10)  # now waiting for the next tick
    loop.stop()
    assert not loop.running
    assert urgent == []


def test_after_each_tick_it_reports_the_ticks_lateness_and_duration() -> None:
    reported: list[tuple[int, float, float]] = []
    loop: ControlLoop

    def after_tick(lateness_s: float, duration_s: float) -> None:
        reported.append((loop.ticks, lateness_s, duration_s))

    loop = ControlLoop(lambda now_s: time.sleep(0.002), hz=100.0, after_tick=after_tick)
    loop.start()
    deadline_s = time.monotonic() + 5.0
    while len(reported) < 5 and time.monotonic() < deadline_s:
        time.sleep(0.01)
    loop.stop()
    assert len(reported) >= 5
    # Once per tick, after it is counted; the duration covers the tick's own work.
    assert [tick for tick, _, _ in reported[:5]] == [1, 2, 3, 4, 5]
    assert all(duration_s >= 0.002 and lateness_s >= 0.0 for _, lateness_s, duration_s in reported)


def test_it_pins_itself_to_the_cpu_asked_for_or_says_why_not() -> None:
    allowed = os.sched_getaffinity(0)
    cpu = sorted(allowed)[0]
    seen: list[set[int]] = []
    loop = ControlLoop(lambda now_s: seen.append(os.sched_getaffinity(0)), hz=100.0, cpu=cpu)
    loop.start()
    deadline_s = time.monotonic() + 5.0
    while not seen and time.monotonic() < deadline_s:
        time.sleep(0.01)
    loop.stop()
    assert seen[0] == {cpu}
    assert loop.pinned_cpu == cpu
    assert os.sched_getaffinity(0) == allowed  # only its own thread
    # A CPU the process may not use: no pinning, and the loop runs anyway.
    refused = ControlLoop(lambda now_s: None, hz=100.0, cpu=4095)
    refused.start()
    deadline_s = time.monotonic() + 5.0
    while refused.ticks == 0 and time.monotonic() < deadline_s:
        time.sleep(0.01)
    refused.stop()
    assert refused.ticks > 0
    assert refused.pinned_cpu is None
