"""``basestation.cpu_slots``: at most N requests run the application at once, the exempt ones
(the stop) aside; a slot comes back when the answer is closed, or while a request only waits."""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest

from basestation.cpu_slots import CpuSlots, slot_released

DEADLINE_S = 10.0  # bounds a hang only


class _Counting:
    """A WSGI app that records how many of its calls run at once; each waits for ``go``."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.running = 0
        self.most = 0
        self.go = threading.Event()
        self.waiting_released = False

    def __call__(self, environ: dict[str, Any], start_response: Any) -> list[bytes]:
        with self.lock:
            self.running += 1
            self.most = max(self.most, self.running)
        try:
            if environ.get("PATH_INFO") == "/wait":
                with slot_released():
                    self.go.wait(DEADLINE_S)
            else:
                self.go.wait(DEADLINE_S)
        finally:
            with self.lock:
                self.running -= 1
        start_response("200 OK", [])
        return [b"ok"]


def _call(app: CpuSlots, path: str, done: list[str]) -> None:
    result = app({"PATH_INFO": path, "REQUEST_METHOD": "GET"}, lambda *a: None)
    try:
        done.append(b"".join(result).decode())
    finally:
        close = getattr(result, "close", None)  # an exempt call's answer is the app's own
        if close is not None:
            close()


def _wait_for(check: Any) -> None:
    deadline = time.monotonic() + DEADLINE_S
    while not check():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


@pytest.mark.parametrize("slots", [1, 2, 3])
def test_no_more_than_the_slots_run_at_once_and_every_call_ends(slots):
    inner = _Counting()
    app = CpuSlots(inner, slots, exempt=lambda environ: False)
    done: list[str] = []
    calls = [threading.Thread(target=_call, args=(app, "/read", done)) for _ in range(8)]
    for call in calls:
        call.start()
    _wait_for(lambda: inner.running == slots)
    time.sleep(0.05)  # the others had every chance to enter: they must not have
    assert inner.running == slots
    inner.go.set()
    for call in calls:
        call.join(DEADLINE_S)
    assert done == ["ok"] * 8
    assert inner.most == slots


def test_an_exempt_request_runs_while_every_slot_is_held():
    inner = _Counting()
    app = CpuSlots(inner, 1, exempt=lambda environ: environ["PATH_INFO"] == "/stop")
    done: list[str] = []
    holder = threading.Thread(target=_call, args=(app, "/read", done))
    holder.start()
    _wait_for(lambda: inner.running == 1)
    stop = threading.Thread(target=_call, args=(app, "/stop", done))
    stop.start()
    _wait_for(lambda: inner.running == 2)  # the stop is in, beside the slot's holder
    inner.go.set()
    for call in (holder, stop):
        call.join(DEADLINE_S)
    assert done == ["ok", "ok"]


def test_a_waiting_request_lends_its_slot_and_takes_it_back():
    inner = _Counting()
    app = CpuSlots(inner, 1, exempt=lambda environ: False)
    done: list[str] = []
    waiter = threading.Thread(target=_call, args=(app, "/wait", done))
    waiter.start()
    _wait_for(lambda: inner.running == 1)
    reader = threading.Thread(target=_call, args=(app, "/read", done))
    reader.start()
    _wait_for(lambda: inner.running == 2)  # in, on the slot the waiter lent
    inner.go.set()
    for call in (waiter, reader):
        call.join(DEADLINE_S)
    assert done == ["ok", "ok"]
    # Every slot is back: one more call gets in at once.
    inner.go.clear()
    last = threading.Thread(target=_call, args=(app, "/read", done))
    last.start()
    _wait_for(lambda: inner.running == 1)
    inner.go.set()
    last.join(DEADLINE_S)


def test_an_application_that_raises_gives_its_slot_back():
    def broken(environ: dict[str, Any], start_response: Any) -> list[bytes]:
        raise RuntimeError("broken")

    app = CpuSlots(broken, 1, exempt=lambda environ: False)
    for _ in range(3):  # a slot lost to the first would hang the second
        with pytest.raises(RuntimeError):
            app({"PATH_INFO": "/", "REQUEST_METHOD": "GET"}, lambda *a: None)
