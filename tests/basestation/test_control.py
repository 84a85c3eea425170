"""The control loop thread: rate, absolute deadlines, late and skipped ticks."""

from __future__ import annotations

import time

from basestation.control import ControlLoop


def test_it_ticks_at_its_rate_on_absolute_deadlines() -> None:
    stamps: list[float] = []
    loop = ControlLoop(lambda now_s: stamps.append(time.monotonic()), hz=50.0)
    loop.start()
    time.sleep(0.6)
    loop.stop()
    assert not loop.running
    # ~30 ticks in 0.6 s; generous bounds because the test machine may be busy.
    assert 20 <= loop.ticks <= 32
    assert loop.ticks == len(stamps)
    # Absolute deadlines: the k-th tick is near start + k/50 s, with no accumulated drift.
    offsets = [(stamp - stamps[0]) - k * 0.02 for k, stamp in enumerate(stamps)]
    if loop.skipped_ticks == 0:
        assert sorted(offsets)[len(offsets) // 2] < 0.005


def test_it_passes_the_wall_clock_to_the_tick() -> None:
    seen: list[float] = []
    loop = ControlLoop(seen.append, hz=100.0)
    loop.start()
    time.sleep(0.1)
    loop.stop()
    assert seen
    assert abs(seen[-1] - time.time()) < 1.0


def test_it_counts_a_slow_tick_as_late_and_skips_the_missed_slots() -> None:
    calls: list[float] = []

    def tick(now_s: float) -> None:
        calls.append(now_s)
        if len(calls) == 3:
            time.sleep(0.1)  # five periods at 50 Hz

    loop = ControlLoop(tick, hz=50.0)
    loop.start()
    time.sleep(0.4)
    loop.stop()
    assert loop.late_ticks >= 1
    assert loop.skipped_ticks >= 3
    assert loop.max_lateness_s >= 0.06
    # 0.4 s at 50 Hz is 20 slots; the slow tick ate ~5 of them and no burst made them up.
    assert loop.ticks <= 17


def test_it_survives_a_failing_tick() -> None:
    calls: list[float] = []

    def tick(now_s: float) -> None:
        calls.append(now_s)
        if len(calls) == 2:
            raise RuntimeError("radio hiccup")

    loop = ControlLoop(tick, hz=100.0)
    loop.start()
    time.sleep(0.1)
    loop.stop()
    assert loop.tick_errors == 1
    assert len(calls) > 3


def test_it_reports_lateness_and_duration_percentiles_over_its_window() -> None:
    def tick(now_s: float) -> None:
        time.sleep(0.002)

    loop = ControlLoop(tick, hz=100.0)
    assert loop.stats().window.ticks == 0
    assert loop.stats().window.lateness_p99_s is None
    loop.start()
    time.sleep(0.3)
    loop.stop()
    stats = loop.stats()
    window = stats.window
    assert window.ticks == stats.ticks
    assert window.lateness_p50_s is not None
    assert window.lateness_p99_s is not None
    assert window.lateness_max_s is not None
    assert 0 <= window.lateness_p50_s <= window.lateness_p99_s <= window.lateness_max_s
    assert window.lateness_max_s <= stats.max_lateness_s
    assert window.duration_p50_s is not None
    assert window.duration_p50_s >= 0.002
    assert stats.window_s == 60.0


def test_its_window_holds_the_last_minute_of_ticks() -> None:
    seen = 0

    def tick(now_s: float) -> None:
        nonlocal seen
        seen += 1

    loop = ControlLoop(tick, hz=200.0)  # a window of 12 000 ticks
    loop.start()
    time.sleep(0.1)
    loop.stop()
    assert loop.stats().window.ticks == min(seen, 12_000)


def test_a_wake_runs_the_urgent_call_between_ticks_without_moving_the_grid() -> None:
    ticks: list[float] = []
    urgent: list[float] = []
    loop = ControlLoop(
        lambda now_s: ticks.append(time.monotonic()),
        hz=2.0,  # ticks 0.5 s apart: an urgent call in between cannot be a tick
        urgent=lambda now_s: urgent.append(time.monotonic()),
    )
    loop.start()
    try:
        time.sleep(0.1)
        woken_s = time.monotonic()
        loop.wake()
        deadline_s = time.monotonic() + 0.35
        while not urgent and time.monotonic() < deadline_s:
            time.sleep(0.005)
        assert len(urgent) == 1
        assert loop.urgent_calls == 1
        assert len(ticks) == 1  # the first tick, at start; the second is not due yet
        assert urgent[0] >= woken_s
        time.sleep(0.5)
    finally:
        loop.stop()
    # The grid is where it was: the second tick half a period after the first, not after
    # the urgent call.
    assert len(ticks) >= 2
    assert abs((ticks[1] - ticks[0]) - 0.5) < 0.1


def test_stop_is_not_taken_for_a_wake() -> None:
    urgent: list[float] = []
    loop = ControlLoop(lambda now_s: None, hz=2.0, urgent=urgent.append)
    loop.start()
    time.sleep(0.05)
    loop.stop()
    assert not loop.running
    assert urgent == []


def test_it_calls_urgent_once_at_the_instant_urgent_at_names_between_ticks() -> None:
    ticks: list[float] = []
    urgent: list[float] = []
    at_s = time.time() + 0.2  # between the first tick (at start) and the second (0.5 s)
    loop = ControlLoop(
        lambda now_s: ticks.append(now_s),
        hz=2.0,
        urgent=urgent.append,
        urgent_at=lambda: at_s,
    )
    loop.start()
    try:
        time.sleep(0.35)
        assert len(urgent) == 1  # at the instant, and only once though still asked for
        assert urgent[0] >= at_s
        assert len(ticks) == 1
        time.sleep(0.3)
    finally:
        loop.stop()
    assert len(urgent) == 1
    assert len(ticks) >= 2
