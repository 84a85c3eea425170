"""How many of the agent's requests run Python at once: its "CPU slots".

The agent's HTTP threads share one interpreter lock. Every thread that can run competes for
it, and a thread that has just made a system call (a socket read, the control loop's pipe)
waits for it behind all the others: with eight threads serialising pages for fifty readers,
each of the stop's few system calls waited behind the readers' work, and the stop's p95 went
from 10 ms to over 100 ms on a loaded two-core machine. More threads than cores of Python
buy no throughput either (measured in docs/performance.md "Emergency stop under HTTP load").

So the request threads stay many (a collector's long-poll holds one for up to 30 s), but at
most ``slots`` of them run a request at a time; the others wait on a semaphore, which costs
no interpreter time. A request gives its slot back while it only waits (the long-poll's
wait for new samples: :func:`slot_released`). The emergency stop takes no slot: it is served
on threads of its own (``basestation.serve.StopFirstDispatcher``) and competes only with the
requests that hold slots.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Any

WsgiApp = Callable[[dict[str, Any], Callable[..., Any]], Iterable[bytes]]

# Two: one request computing while another finishes a write or waits on the store.
DEFAULT_SLOTS = 2

_held = threading.local()


class CpuSlots:
    """WSGI middleware: ``app`` run by at most ``slots`` requests at once, except the paths
    for which ``exempt(environ)`` is true. A request holds its slot until its answer has been
    written (a streamed body runs Python too) or the server closes it."""

    def __init__(self, app: WsgiApp, slots: int, exempt: Callable[[dict[str, Any]], bool]):
        if slots < 1:
            raise ValueError("at least one CPU slot")
        self.app = app
        self.slots = slots
        self.exempt = exempt
        self._semaphore = threading.BoundedSemaphore(slots)

    def __call__(self, environ: dict[str, Any], start_response: Callable[..., Any]) -> Any:
        if self.exempt(environ):
            return self.app(environ, start_response)
        self._take()
        try:
            result = self.app(environ, start_response)
        except BaseException:
            self._give()
            raise
        return _ReleasedOnClose(result, self._give)

    def _take(self) -> None:
        self._semaphore.acquire()
        _held.slots = self

    def _give(self) -> None:
        if getattr(_held, "slots", None) is self:
            _held.slots = None
            self._semaphore.release()

    @contextlib.contextmanager
    def released(self) -> Iterator[None]:
        self._semaphore.release()
        _held.slots = None
        try:
            yield
        finally:
            self._take()


class _ReleasedOnClose:
    """The app's answer, its slot given back when the server closes it (PEP 3333: the
    server calls ``close`` whether or not the body was read to its end)."""

    def __init__(self, result: Iterable[bytes], release: Callable[[], None]) -> None:
        self._result = result
        self._release = release

    def __iter__(self) -> Iterator[bytes]:
        return iter(self._result)

    def close(self) -> None:
        try:
            close = getattr(self._result, "close", None)
            if close is not None:
                close()
        finally:
            self._release()


@contextlib.contextmanager
def slot_released() -> Iterator[None]:
    """Give this request's CPU slot to another while the block only waits; nothing to give
    when it holds none (no server with slots, a test client, an exempt path)."""
    slots: CpuSlots | None = getattr(_held, "slots", None)
    if slots is None:
        yield
        return
    with slots.released():
        yield
