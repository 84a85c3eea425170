"""The control loop in its own process, so that HTTP can never hold it up.

Why a process: in one process the loop's thread competes for the GIL with every HTTP
thread, and each hand-over can cost a switch interval; at 50 Hz under 50 clients that made
ticks up to 37 ms late. In its own process the loop shares the GIL only with the store
writer and the thread that takes the API's requests, and runs real-time where allowed.

Who holds what:

- The **loop process** (:func:`loop_main`) owns the robot (radio, SPI or simulator), the
  :class:`~basestation.manager.RunManager` (the tick and its ``decide``, unchanged), the store
  writer and the e-stop latch and manual command in force.
- The **agent process** (:class:`LoopProcess`) serves HTTP. It reads and writes runs in the
  run store directly (SQLite WAL: several processes, one file), and reaches the loop through
  two local channels:

  * requests (a pipe; each answered): a run changed, e-stop, release, manual drive. The
    loop process's request thread calls the manager's own methods, as HTTP threads did when
    both lived in one process, so an e-stop still wakes the loop between two ticks;
  * state (datagrams, loop → agent, after every tick and every request): the snapshot that
    ``/status`` shows, the loop's counters and each tick's lateness. The loop sends without
    blocking and never waits for the agent: a stalled agent only misses states.

The agent process supervises its loop process: one that dies is reported (``/status``
faults, ``/healthz``) and started again; meanwhile the robot hears nothing and its firmware's
500 ms dead-man stops it. The loop process stops cleanly (robot to zero, the run
interrupted) when the agent asks, on SIGTERM, and when the agent process dies (Linux: the
parent-death signal; elsewhere the pipe's end).

One thing: the two ends of one pipe — the control loop's process and the agent's handle to it
(:class:`LoopProcess`); their messages change together.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import gc
import logging
import math
import multiprocessing
import os
import pickle
import select
import signal
import socket
import sys
import threading
import time
import types
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from basestation.config import AUTO_CPU, AgentConfig, ConfigError
from basestation.control import (
    STATS_WINDOW_S,
    ControlLoop,
    ControlStats,
    WindowStats,
    window_of,
)
from basestation.errors import RunConflict
from basestation.logs import configure_logging, current_log_format
from basestation.manager import RunManager
from basestation.robot import Direction, RobotLimits
from basestation.robots import build_robot
from basestation.store import RunStore
from basestation.tick_rules import AgentSnapshot, EstopLatch, ManualDrive

logger = logging.getLogger(__name__)

# How long the agent waits for its loop process to open the store and the robot (the radio
# configures the robot over the air: three attempts with their timeouts).
READY_TIMEOUT_S = 30.0
# How long an API request to the loop process may take before the HTTP call fails: long
# enough for a store write under load, short enough that a hung loop is seen as one.
REQUEST_TIMEOUT_S = 5.0
# How long the loop process may take to stop the robot and close the store.
STOP_TIMEOUT_S = 10.0
# A loop process that dies is started again after this pause (and no faster than this
# even when it dies at once, so a crash loop does not spin).
RESTART_DELAY_S = 1.0
# No state from a live loop process for this long and it counts as not running (stopped,
# hung): /status reports the fault, /healthz fails.
STALE_AFTER_S = 1.0
# At most this many ticks' lateness in one state datagram (the rest waits for the next).
MAX_TIMINGS_PER_STATE = 1000
# Linux prctl(2) option: the signal this process gets when its parent thread dies.
PR_SET_PDEATHSIG = 1


def pick_cpu(requested: int | None) -> int | None:
    """The CPU to pin the loop's thread to: ``requested``, or for AUTO_CPU the last one this
    process may use when it may use two or more (None: no pinning)."""
    if requested != AUTO_CPU:
        return requested
    try:
        allowed = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return None
    return allowed[-1] if len(allowed) >= 2 else None


@dataclass(frozen=True)
class LoopInfo:
    """What the loop process says once it is ready."""

    pid: int
    rail_length_m: float
    robot_limits: RobotLimits | None
    # How runs are made here (basestation/provenance.py), as the loop's manager records it.
    agent_facts: dict[str, Any] | None = None
    firmware_facts: dict[str, Any] | None = None


@dataclass(frozen=True)
class LoopState:
    """The loop process's state after a tick or a request (one datagram)."""

    pid: int
    api_version: int  # requests handled so far: orders this against request answers
    snapshot: AgentSnapshot
    estop: EstopLatch | None
    manual: ManualDrive | None
    ticks: int
    late_ticks: int
    skipped_ticks: int
    tick_errors: int
    max_lateness_s: float
    realtime: bool
    pinned_cpu: int | None
    writer_alive: bool
    # (tick number, lateness, duration) of the ticks since the last state the agent got.
    timings: tuple[tuple[int, float, float], ...] = ()


# -- the loop process ------------------------------------------------------------------------


class _Termination:
    """Set by SIGTERM (or the agent's death); the main thread's wait wakes through the
    signal's wake-up socket and reads it.

    A plain attribute, not a ``threading.Event``: a handler runs on the main thread between
    two of its bytecodes, possibly while that thread is inside ``Event.set`` for the previous
    SIGTERM (the agent's death and a stop from its process group come together), and the
    Event's lock is not reentrant: the process hung for good there, its loop ticking on. The
    handler only sets it: raising from a handler could cut the clean-up short, robot stop
    included."""

    requested = False


def _on_sigterm(signum: int, frame: types.FrameType | None) -> None:
    _Termination.requested = True


def _die_with_parent(parent_pid: int) -> bool:
    """Linux: SIGTERM when the agent process dies (SIGKILL included), so the loop never
    drives on without it. Elsewhere the request pipe's end tells the same, a little later.
    False when the agent has died already."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
        except (OSError, AttributeError) as exc:
            logger.warning("no parent-death signal (%s): the pipe's end stops the loop", exc)
    return os.getppid() == parent_pid


def _realtime_helpers(rt_priority: int) -> None:
    """Run this thread, and so every thread it starts (the store writer; they inherit it),
    under SCHED_FIFO one step below the tick's own priority. Why: a helper that holds the GIL
    when the kernel preempts it for some busy normal process keeps the tick waiting until it
    runs again (tens of ms on a loaded machine). Real-time, the helpers are never preempted
    by normal processes, and they only ever run briefly."""
    if rt_priority <= 0:
        return
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(max(1, rt_priority - 1)))
    except (OSError, AttributeError) as exc:
        logger.warning("the loop's helper threads stay at normal priority (%s)", exc)


def _pin_process(cpu: int) -> None:
    """Keep every thread of this process (the request thread, the store writer, the robot
    link's) on the tick's CPU. Why: a helper holding the GIL on another CPU holds up the tick
    whenever that CPU is taken away, by an interrupt or, on a virtual machine, by the host (a
    stall of 10-20 ms on the other CPU was seen to make the tick as late). On its own CPU the
    tick preempts a helper, which hands the GIL over within the switch interval. The loop's
    thread pins itself too and says so; a refusal here is only logged."""
    tasks = Path("/proc/self/task")
    tids = [int(t.name) for t in tasks.iterdir()] if tasks.is_dir() else [0]
    for tid in tids:
        try:
            os.sched_setaffinity(tid, {cpu})
        except (OSError, AttributeError, ValueError) as exc:
            logger.warning("the loop's helper threads not pinned to CPU %d (%s)", cpu, exc)
            return


def _orphaned(parent_pid: int, wait_s: float = 0.2) -> bool:
    """Whether the agent's process is gone. Its death signal can come as its first thread
    dies, a moment before the kernel hands us to a new parent: look for that moment."""
    deadline_s = time.monotonic() + wait_s
    while os.getppid() == parent_pid:
        if time.monotonic() >= deadline_s:
            return False
        time.sleep(0.01)
    return True


class _Publisher:
    """Sends the loop's state to the agent process without ever blocking the loop."""

    def __init__(
        self, sock: socket.socket, manager: RunManager, loop: ControlLoop | None = None
    ) -> None:
        sock.setblocking(False)
        self.sock = sock
        self.manager = manager
        self.loop = loop
        self.api_version = 0
        self._timings: list[tuple[int, float, float]] = []
        self._lock = threading.Lock()  # the tick and the request thread both publish
        self.dropped = 0

    def after_tick(self, lateness_s: float, duration_s: float) -> None:
        loop = self.loop
        tick = 0 if loop is None else loop.ticks
        with self._lock:
            self._timings.append((tick, lateness_s, duration_s))
            if len(self._timings) > MAX_TIMINGS_PER_STATE:
                del self._timings[:-MAX_TIMINGS_PER_STATE]
        self.publish()

    def publish(self) -> None:
        manager = self.manager
        loop = self.loop
        with self._lock:
            state = LoopState(
                pid=os.getpid(),
                api_version=self.api_version,
                snapshot=manager.snapshot,
                estop=manager.estop,
                manual=manager.manual(time.time()),
                ticks=0 if loop is None else loop.ticks,
                late_ticks=0 if loop is None else loop.late_ticks,
                skipped_ticks=0 if loop is None else loop.skipped_ticks,
                tick_errors=0 if loop is None else loop.tick_errors,
                max_lateness_s=0.0 if loop is None else loop.max_lateness_s,
                realtime=loop is not None and loop.realtime,
                pinned_cpu=None if loop is None else loop.pinned_cpu,
                writer_alive=manager.writer.alive,
                timings=tuple(self._timings),
            )
            try:
                self.sock.send(pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL))
            except (BlockingIOError, InterruptedError):
                self.dropped += 1  # the agent is behind: its timings come with the next one
                return
            except OSError:
                return  # the agent is gone; the request pipe's end stops this process
            self._timings.clear()


def loop_main(
    config: AgentConfig,
    requests: Connection,
    state_sock: socket.socket,
    parent_pid: int,
    log_level: int,
    restart: bool = False,
    log_format: str = "plain",
) -> None:
    """The loop process: open the store and the robot, say ready, tick until told to stop."""
    configure_logging(level=log_level, log_format=log_format)
    # Ctrl-C reaches the whole process group: the agent stops us in order, robot first.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # A signal wakes the main thread's select() through this socket.
    signal_wake, signal_sink = socket.socketpair()
    signal_sink.setblocking(False)
    signal.set_wakeup_fd(signal_sink.fileno(), warn_on_full_buffer=False)
    signal.signal(signal.SIGTERM, _on_sigterm)
    if not _die_with_parent(parent_pid):
        return
    # The loop shares the GIL with the writer and the request thread only; still, a 1 ms
    # switch interval bounds what either can make the tick wait.
    sys.setswitchinterval(0.001)
    _realtime_helpers(config.rt_priority)
    store = RunStore(config.store_path)
    try:
        # A run still marked running was cut off (agent or loop process killed): its samples
        # are kept, its state says why it stopped.
        reason = "control loop restarted during run" if restart else "agent restarted during run"
        store.mark_interrupted(now_s=time.time(), reason=reason)
        robot = build_robot(config)
    except ConfigError as exc:
        store.close()
        requests.send(("error", str(exc)))
        return
    manager = RunManager(store=store, robot=robot, config=config)
    limits = getattr(robot, "limits", None)
    requests.send(
        (
            "ready",
            LoopInfo(
                pid=os.getpid(),
                rail_length_m=manager.rail_length_m,
                robot_limits=limits if isinstance(limits, RobotLimits) else None,
                agent_facts=manager.agent_facts,
                firmware_facts=manager.firmware_facts,
            ),
        )
    )
    # Everything loaded so far lives as long as the process: out of the collector's full
    # passes, which hold the GIL (and so the tick) for their whole length.
    gc.collect()
    gc.freeze()
    cpu = pick_cpu(config.control_cpu)
    if cpu is not None:
        _pin_process(cpu)  # before the writer starts: it inherits the CPU
    publisher = _Publisher(state_sock, manager)
    manager.writer.start()
    loop = ControlLoop(
        manager.tick,
        hz=config.control_hz,
        rt_priority=config.rt_priority,
        cpu=cpu,
        urgent=manager.urgent,
        urgent_at=manager.next_start_s,
        after_tick=publisher.after_tick,
    )
    publisher.loop = loop
    manager.on_wake = loop.wake
    loop.start()
    asked = False
    try:
        asked = _serve_requests(requests, signal_wake, manager, publisher)
    except (EOFError, OSError):
        pass
    finally:
        loop.stop()
        # Orphaned: the agent's process died (its death sent us SIGTERM, or closed the pipe).
        orphaned = not asked and _orphaned(parent_pid)
        try:
            manager.shutdown(
                time.time(), "agent died during run" if orphaned else "agent stopped during run"
            )
        finally:
            manager.writer.stop()
            store.close()
            close_robot = getattr(robot, "close", None)
            if close_robot is not None:
                close_robot()
            logger.info("control loop process %d stopped", os.getpid())


def _serve_requests(
    requests: Connection, signal_wake: socket.socket, manager: RunManager, publisher: _Publisher
) -> bool:
    """Answer the agent's requests, one at a time, until it says stop (True), or SIGTERM
    comes or the agent goes away (False)."""
    while not _Termination.requested:
        readable, _, _ = select.select([requests.fileno(), signal_wake.fileno()], [], [])
        if signal_wake.fileno() in readable:
            with contextlib.suppress(OSError):
                signal_wake.recv(64)
            continue
        message = requests.recv()
        request_id, operation, kwargs = message
        if operation == "stop":
            return True
        try:
            result: Any = _apply(manager, operation, kwargs)
            answer: tuple[Any, ...] = ("ok", result)
        except RunConflict as exc:
            answer = ("conflict", (exc.kind, exc.detail))
        except Exception as exc:  # the HTTP call fails with 500; the loop goes on
            logger.exception("request %s failed", operation)
            answer = ("error", f"{type(exc).__name__}: {exc}")
        publisher.api_version += 1
        now_s = time.time()
        view = (publisher.api_version, manager.estop, manager.manual(now_s))
        requests.send((request_id, *answer, view))
        publisher.publish()
    return False


def _apply(manager: RunManager, operation: str, kwargs: dict[str, Any]) -> Any:
    if operation == "runs_changed":
        manager.notify_runs_changed()
        return None
    if operation == "latch_estop":
        return manager.latch_estop(**kwargs)
    if operation == "release_estop":
        return manager.release_estop(**kwargs)
    if operation == "drive_manually":
        return manager.drive_manually(**kwargs)
    raise ValueError(f"unknown request {operation!r}")


# -- the agent's side ------------------------------------------------------------------------


class LoopUnavailable(Exception):
    """The loop process did not answer (dead, restarting or hung)."""


class LoopProcess:
    """The agent's handle on its control-loop process: starts and supervises it, forwards the
    API's requests, and keeps the loop's latest state for ``/status``.

    It offers what the API needs of the run manager (:class:`basestation.manager.RunControl`).
    """

    def __init__(self, config: AgentConfig) -> None:
        self.config = config
        self.hz = config.control_hz
        self.restarts = 0
        self.info: LoopInfo | None = None
        self._process: Any = None  # multiprocessing's SpawnProcess
        self._requests: Connection | None = None
        self._state_sock: socket.socket | None = None
        self._request_lock = threading.Lock()
        self._next_request_id = 0
        self._closing = threading.Event()
        self._ready = threading.Event()
        self._start_error: BaseException | None = None
        self._supervisor: threading.Thread | None = None
        # What the loop process last said (whole objects swapped, read lock-free).
        self._state: LoopState | None = None
        self._state_at_s: float | None = None  # monotonic
        # The supervisor thread and a caller catching up (``running``) both take states.
        self._drain_lock = threading.Lock()
        self._view: tuple[int, EstopLatch | None, ManualDrive | None] = (0, None, None)
        self._view_lock = threading.Lock()
        self._ring_size = max(1, math.ceil(STATS_WINDOW_S * config.control_hz))
        self._lateness_ring = [0.0] * self._ring_size
        self._duration_ring = [0.0] * self._ring_size
        self._ring_count = 0
        self._last_tick_seen = 0
        self._window_cache: tuple[int, WindowStats] = (-1, WindowStats())

    # -- life cycle ------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the loop process and wait until it is ticking. Raises ConfigError when it
        refuses the configuration (bad rail file, limit above the robot's hard maximum)."""
        # The supervisor thread spawns every loop process: on Linux the loop's parent-death
        # signal follows the thread that started it, and this one lives until close().
        self._supervisor = threading.Thread(
            target=self._supervise, name="loop-supervisor", daemon=True
        )
        self._supervisor.start()
        if not self._ready.wait(READY_TIMEOUT_S + 5.0):
            self.close()
            raise RuntimeError("the control loop process did not start")
        if self._start_error is not None:
            error = self._start_error
            self.close()
            raise error

    def close(self) -> None:
        """Stop the loop process (robot to zero, current run interrupted). Idempotent."""
        if self._closing.is_set():
            return
        self._closing.set()
        if self._supervisor is not None and self._supervisor is not threading.current_thread():
            self._supervisor.join(STOP_TIMEOUT_S + 10.0)

    @property
    def pid(self) -> int | None:
        process = self._process
        return None if process is None else process.pid

    @property
    def alive(self) -> bool:
        process = self._process
        return process is not None and process.is_alive()

    @property
    def running(self) -> bool:
        """Alive and publishing: ticks reach the robot."""
        at_s = self._state_at_s
        if not self.alive or at_s is None:
            return False
        stale_after_s = max(STALE_AFTER_S, 5.0 / self.hz)
        if time.monotonic() - at_s > stale_after_s:
            # This process may be the one that stood still (starved, stopped, swapped out)
            # while the loop kept sending: read what waits before judging the loop.
            sock = self._state_sock
            if sock is not None:
                self._drain(sock)
            at_s = self._state_at_s or at_s
        state = self._state
        # Before its first state: the grace from its start (_state_at_s is set then).
        fresh = time.monotonic() - at_s <= stale_after_s
        return fresh and (state is None or state.writer_alive)

    def _spawn(self) -> None:
        context = multiprocessing.get_context("spawn")
        parent_requests, child_requests = context.Pipe(duplex=True)
        parent_state, child_state = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
        process = context.Process(
            target=loop_main,
            args=(
                self.config,
                child_requests,
                child_state,
                os.getpid(),
                logging.getLogger().getEffectiveLevel(),
                self.restarts > 0,
                current_log_format(),
            ),
            name="amazing-agent-loop",
            daemon=True,
        )
        process.start()
        child_requests.close()
        child_state.close()
        parent_state.setblocking(False)
        # Until it says ready, nothing else reads the pipe.
        if not parent_requests.poll(READY_TIMEOUT_S):
            process.kill()
            process.join(5)
            parent_requests.close()
            parent_state.close()
            raise RuntimeError("the control loop process did not get ready")
        try:
            kind, payload = parent_requests.recv()
        except EOFError:
            process.join(5)
            parent_requests.close()
            parent_state.close()
            raise RuntimeError(
                f"the control loop process exited at start (exit code {process.exitcode})"
            ) from None
        if kind == "error":
            process.join(5)
            parent_requests.close()
            parent_state.close()
            raise ConfigError(payload)
        assert kind == "ready"
        assert isinstance(payload, LoopInfo)
        with self._request_lock:
            old_requests, old_state = self._requests, self._state_sock
            self._process = process
            self._requests = parent_requests
            self._state_sock = parent_state
            self.info = payload
            self._state = None
            self._state_at_s = time.monotonic()  # grace until its first tick
            self._last_tick_seen = 0
        for old in (old_requests, old_state):
            if old is not None:
                old.close()
        logger.info("control loop process %d started (%g Hz)", payload.pid, self.hz)

    def _supervise(self) -> None:
        try:
            self._spawn()
        except BaseException as exc:
            self._start_error = exc
            self._ready.set()
            return
        self._ready.set()
        while not self._closing.is_set():
            process = self._process
            sock = self._state_sock
            assert sock is not None
            readable, _, _ = select.select([sock, process.sentinel], [], [], 0.2)
            if sock in readable:
                self._drain(sock)
            if process.sentinel in readable and not self._closing.is_set():
                self._drain(sock)
                self._restart(process)
        self._stop_process()

    def _restart(self, dead: Any) -> None:
        dead.join(1)
        logger.error(
            "control loop process %d died (exit code %s); the robot stops on its dead-man; "
            "starting it again",
            dead.pid,
            dead.exitcode,
        )
        self.restarts += 1
        died_s = time.monotonic()
        while not self._closing.is_set():
            self._closing.wait(max(0.0, RESTART_DELAY_S - (time.monotonic() - died_s)))
            if self._closing.is_set():
                return
            try:
                self._spawn()
                return
            except (RuntimeError, ConfigError, OSError) as exc:
                logger.error("control loop process did not start again: %s", exc)
                died_s = time.monotonic()

    def _stop_process(self) -> None:
        process = self._process
        if process is None:
            return
        if process.is_alive():
            with contextlib.suppress(LoopUnavailable):
                self._request("stop", {}, expect_answer=False)
            process.join(STOP_TIMEOUT_S)
            if process.is_alive():
                logger.error("control loop process did not stop in time: terminating it")
                process.terminate()
                process.join(5)
            if process.is_alive():
                process.kill()
                process.join(5)
        with self._request_lock:
            for channel in (self._requests, self._state_sock):
                if channel is not None:
                    channel.close()
            self._requests = None
            self._state_sock = None

    # -- state from the loop -----------------------------------------------------------------------

    def _drain(self, sock: socket.socket) -> None:
        with self._drain_lock:
            self._drain_unlocked(sock)

    def _drain_unlocked(self, sock: socket.socket) -> None:
        while True:
            try:
                data = sock.recv(1 << 20)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            if not data:
                return
            state = pickle.loads(data)  # noqa: S301 - our own child, over a socketpair
            assert isinstance(state, LoopState)
            self._take_state(state)

    def _take_state(self, state: LoopState) -> None:
        for tick, lateness_s, duration_s in state.timings:
            if tick <= self._last_tick_seen:
                continue
            self._last_tick_seen = tick
            slot = self._ring_count % self._ring_size
            self._lateness_ring[slot] = lateness_s
            self._duration_ring[slot] = duration_s
            self._ring_count += 1
        self._take_view(state.api_version, state.estop, state.manual)
        self._state = state
        self._state_at_s = time.monotonic()

    def _take_view(
        self, version: int, estop: EstopLatch | None, manual: ManualDrive | None
    ) -> None:
        with self._view_lock:
            # A state sent before a request's answer must not undo what the answer said.
            if version >= self._view[0]:
                self._view = (version, estop, manual)

    # -- what the API reads ----------------------------------------------------------------------

    @property
    def snapshot(self) -> AgentSnapshot:
        state = self._state
        return AgentSnapshot() if state is None else state.snapshot

    @property
    def estop(self) -> EstopLatch | None:
        return self._view[1]

    def manual(self, now_s: float) -> ManualDrive | None:
        manual = self._view[2]
        return manual if manual is not None and now_s < manual.expires_at_s else None

    @property
    def rail_length_m(self) -> float:
        info = self.info
        return self.config.rail_length_m if info is None else info.rail_length_m

    @property
    def robot_limits(self) -> RobotLimits | None:
        info = self.info
        return None if info is None else info.robot_limits

    @property
    def agent_facts(self) -> dict[str, Any] | None:
        info = self.info
        return None if info is None else info.agent_facts

    @property
    def firmware_facts(self) -> dict[str, Any] | None:
        info = self.info
        return None if info is None else info.firmware_facts

    @property
    def realtime(self) -> bool:
        state = self._state
        return state is not None and state.realtime

    @property
    def pinned_cpu(self) -> int | None:
        state = self._state
        return None if state is None else state.pinned_cpu

    def stats(self) -> ControlStats:
        state = self._state
        return ControlStats(
            hz=self.hz,
            running=self.running,
            ticks=0 if state is None else state.ticks,
            late_ticks=0 if state is None else state.late_ticks,
            skipped_ticks=0 if state is None else state.skipped_ticks,
            tick_errors=0 if state is None else state.tick_errors,
            max_lateness_s=0.0 if state is None else state.max_lateness_s,
            window=self._window_stats(),
        )

    def _window_stats(self) -> WindowStats:
        count = self._ring_count
        cached_count, cached = self._window_cache
        if cached_count == count:
            return cached
        stats = window_of(self._lateness_ring, self._duration_ring, min(count, self._ring_size))
        self._window_cache = (count, stats)
        return stats

    # -- what the API asks -----------------------------------------------------------------------

    def notify_runs_changed(self) -> None:
        """A run was staged, cancelled or aborted in the store: the loop re-reads at once.
        Best effort: the loop re-reads the schedule every second anyway."""
        try:
            self._request("runs_changed", {})
        except LoopUnavailable as exc:
            logger.warning("control loop not told of a run change (%s)", exc)

    def latch_estop(self, *, now_s: float, reason: str) -> tuple[EstopLatch, str | None]:
        result = self._request("latch_estop", {"now_s": now_s, "reason": reason})
        assert isinstance(result, tuple)
        return result

    def release_estop(self, *, now_s: float) -> bool:
        return bool(self._request("release_estop", {"now_s": now_s}))

    def drive_manually(
        self,
        *,
        now_s: float,
        user: str,
        velocity_mps: float,
        direction: Direction,
        ttl_s: float,
        force: bool,
    ) -> tuple[ManualDrive | None, str | None]:
        result = self._request(
            "drive_manually",
            {
                "now_s": now_s,
                "user": user,
                "velocity_mps": velocity_mps,
                "direction": direction,
                "ttl_s": ttl_s,
                "force": force,
            },
        )
        assert isinstance(result, tuple)
        return result

    def _request(
        self, operation: str, kwargs: dict[str, Any], *, expect_answer: bool = True
    ) -> Any:
        with self._request_lock:
            channel = self._requests
            if channel is None or not self.alive:
                raise LoopUnavailable("the control loop process is not running")
            self._next_request_id += 1
            request_id = self._next_request_id
            try:
                channel.send((request_id, operation, kwargs))
                if not expect_answer:
                    return None
                deadline_s = time.monotonic() + REQUEST_TIMEOUT_S
                while True:
                    if not channel.poll(max(0.0, deadline_s - time.monotonic())):
                        raise LoopUnavailable(f"no answer to {operation} in {REQUEST_TIMEOUT_S} s")
                    answer = channel.recv()
                    if answer[0] == request_id:
                        break  # older answers belong to requests that timed out
            except (EOFError, OSError) as exc:
                raise LoopUnavailable(f"the control loop process went away ({exc})") from exc
        _, kind, payload, view = answer
        self._take_view(*view)
        if kind == "conflict":
            raise RunConflict(*payload)
        if kind == "error":
            raise RuntimeError(f"the control loop process failed {operation}: {payload}")
        return payload
