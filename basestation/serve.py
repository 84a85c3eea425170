"""``amazing-agent`` / ``python -m basestation``: serve the agent with waitress."""

from __future__ import annotations

import argparse
import gc
import json
import logging
import os
import signal
import sys
import types
from typing import Any

from waitress.channel import HTTPChannel
from waitress.server import BaseWSGIServer, create_server
from waitress.task import ErrorTask, Task, ThreadedTaskDispatcher, WSGITask
from waitress.utilities import Error

from basestation.api.limits import too_large_detail
from basestation.app import MAX_BODY_BYTES, create_app
from basestation.backup import AgentRunning, data_dir_lock
from basestation.config import AgentConfig, ConfigError
from basestation.contract import STOP_PATH
from basestation.cpu_slots import DEFAULT_SLOTS, CpuSlots
from basestation.logs import LOG_FORMATS, configure_logging
from basestation.runtime import get_runtime

logger = logging.getLogger("basestation.serve")

EXIT_CONFIG_ERROR = 2
# How long a thread may hold the GIL while another waits for it. The control loop has its
# own process (basestation.loop_process); here it bounds how long a `POST /stop` waits behind
# threads busy serialising pages of samples. 1 ms costs them a little throughput.
GIL_SWITCH_INTERVAL_S = 0.001
# waitress buffers a request body before the app sees it; the app refuses anything over
# 64 KiB anyway, so there is no point in buffering more than this.
MAX_REQUEST_BODY_BYTES = 1024 * 1024
# The stops' own threads: one stop served while a second waits is plenty (a stop latches in
# a few milliseconds), and every thread more would compete for the interpreter lock.
STOP_THREADS = 2


class _JsonErrorTask(ErrorTask):
    """waitress's own refusals (a body over its buffer, malformed HTTP) in the agent's JSON
    envelope, like every other answer: a 10 MB body gets the 413 a 70 KB one gets from the
    application, naming the application's limit, not waitress's plain text."""

    def execute(self) -> None:
        # The stubs call ``request`` the error; at run time it is the parser that holds it.
        error: Error = self.request.error  # type: ignore[attr-defined]
        detail = too_large_detail(MAX_BODY_BYTES) if error.code == 413 else error.body
        code = str(error.reason).lower().replace(" ", "_")
        body = json.dumps({"error": code, "detail": detail}).encode()
        self.status = f"{error.code} {error.reason}"
        self.response_headers = [("Content-Type", "application/json")]
        self.set_close_on_finish()
        self.content_length = len(body)
        self.write(body)


def _error_task(channel: HTTPChannel, request: Any) -> Task:
    """waitress's refusal of a request, except a stop: a stop whose body is over the server's
    buffer still reaches the agent, without its body (a stop is refused only for its token).

    ``request`` is waitress's parser (its stubs call it the error)."""
    if request.error.code == 413 and is_stop(request):
        request.error = None
        request.body_rcv = None
        request.headers["CONTENT_LENGTH"] = "0"
        task = WSGITask(channel, request)
        task.close_on_finish = True  # the rest of the body is still on its way: hang up
        return task
    return _JsonErrorTask(channel, request)


class _JsonErrorChannel(HTTPChannel):
    error_task_class = staticmethod(_error_task)  # type: ignore[assignment]


class StopFirstDispatcher(ThreadedTaskDispatcher):
    """waitress's task queue with a lane for stops: a connection whose next request is
    ``POST /api/v1/stop`` is served by threads of its own, never queued behind the API's
    readers (docs/basestation.md "The emergency stop, ahead of the queue").

    waitress calls :meth:`add_task` with a channel whose first pending request is the one to
    serve, holding that channel's request lock."""

    def __init__(self, stop_threads: int = STOP_THREADS) -> None:
        super().__init__()
        self.stops = ThreadedTaskDispatcher()
        self.stops.set_thread_count(stop_threads)

    def add_task(self, task: Any) -> None:
        requests = getattr(task, "requests", None)
        if requests and is_stop(requests[0]):
            self.stops.add_task(task)
        else:
            super().add_task(task)

    def shutdown(self, cancel_pending: bool = True, timeout: int = 5) -> bool:
        stops_stopped = self.stops.shutdown(cancel_pending=cancel_pending, timeout=timeout)
        return bool(super().shutdown(cancel_pending=cancel_pending, timeout=timeout)) and bool(
            stops_stopped
        )


def is_stop(request: Any) -> bool:
    """Whether waitress's parsed ``request`` is a stop (its path as the application sees it)."""
    return bool(request.command == "POST" and request.path == STOP_PATH)


def is_stop_environ(environ: dict[str, Any]) -> bool:
    """Whether the WSGI request ``environ`` is a stop: it takes no CPU slot."""
    # Both keys are always there (PEP 3333; waitress sets them for every request).
    return bool(environ["REQUEST_METHOD"] == "POST" and environ["PATH_INFO"] == STOP_PATH)


def _parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="amazing-agent",
        description="AMazING mobile-node base-station agent (configured by AGENT_* variables).",
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on")
    parser.add_argument(
        "--port", type=int, default=8700, help="TCP port (0 picks a free one; see the log)"
    )
    parser.add_argument("--threads", type=int, default=8, help="HTTP worker threads")
    parser.add_argument(
        "--stop-threads",
        type=int,
        default=STOP_THREADS,
        help="threads that serve only POST /api/v1/stop, ahead of the queue (default 2; "
        "0 queues stops with every other request, for comparison)",
    )
    parser.add_argument(
        "--cpu-slots",
        type=int,
        default=DEFAULT_SLOTS,
        help="requests that run at once, the stop aside (default 2; 0: as many as threads, "
        "for comparison); the others wait without competing for the interpreter lock "
        "(basestation/cpu_slots.py)",
    )
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING, ...")
    parser.add_argument(
        "--log-format",
        choices=LOG_FORMATS,
        default=os.environ.get("AGENT_LOG_FORMAT", "plain"),
        help="plain text or one JSON object a line (default: AGENT_LOG_FORMAT, else plain)",
    )
    parser.add_argument(
        "--gil-switch-ms",
        type=float,
        default=GIL_SWITCH_INTERVAL_S * 1000,
        help="Python's thread switch interval (default 1 ms; Python's own default is 5)",
    )
    return parser.parse_args(argv)


class _Stop(SystemExit):
    """Raised in the main thread by the signal handler; waitress stops serving on it."""


def _raise_stop(signum: int, frame: types.FrameType | None) -> None:
    raise _Stop(0)


def main(argv: list[str] | None = None) -> int:
    args = _parse_args(argv)
    configure_logging(level=args.log_level, log_format=args.log_format)
    try:
        config = AgentConfig.from_env()
    except ConfigError as exc:
        print(f"amazing-agent: configuration error: {exc}", file=sys.stderr)
        return EXIT_CONFIG_ERROR

    if not 0.1 <= args.gil_switch_ms <= 100:
        print("amazing-agent: --gil-switch-ms must be between 0.1 and 100", file=sys.stderr)
        return EXIT_CONFIG_ERROR
    sys.setswitchinterval(args.gil_switch_ms / 1000)
    try:
        # Held for the agent's life: a second agent, or a restore of the store
        # (basestation/backup.py), on the same data directory is refused while it runs.
        with data_dir_lock(config.data_dir):
            return _serve(args, config)
    except AgentRunning as exc:
        print(f"amazing-agent: {exc}", file=sys.stderr)
        return 1


def _serve(args: argparse.Namespace, config: AgentConfig) -> int:
    try:
        # The loop's process builds the robot: it reads the rail file and starts the radio,
        # and both can be wrong.
        app = create_app(config)
    except ConfigError as exc:
        print(f"amazing-agent: configuration error: {exc}", file=sys.stderr)
        return EXIT_CONFIG_ERROR
    # Everything loaded so far lives as long as the process: keep it out of the collector's
    # full passes, which hold the GIL for their whole length.
    gc.collect()
    gc.freeze()
    runtime = get_runtime(app)
    try:
        server = make_server(
            app,
            host=args.host,
            port=args.port,
            threads=args.threads,
            stop_threads=args.stop_threads,
            cpu_slots=args.cpu_slots,
        )
    except OSError as exc:
        logger.error("cannot listen on %s:%s: %s", args.host, args.port, exc)
        runtime.close()
        return 1
    port = getattr(server, "effective_port", args.port)
    logger.info(
        "agent %s listening on http://%s:%s, control %g Hz, data dir %s",
        config.resource,
        args.host,
        port,
        config.control_hz,
        config.data_dir.resolve(),
    )
    previous = {sig: signal.signal(sig, _raise_stop) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        server.run()  # returns after SIGTERM/SIGINT (waitress catches the SystemExit)
    except _Stop:
        pass
    finally:
        # A second signal during shutdown must not cut the clean-up short.
        for sig in previous:
            signal.signal(sig, signal.SIG_IGN)
        logger.info("stopping: robot to zero, closing the run store")
        server.close()
        runtime.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    logger.info("agent stopped")
    return 0


def make_server(
    app: Any,
    *,
    host: str,
    port: int,
    threads: int,
    stop_threads: int = STOP_THREADS,
    cpu_slots: int = DEFAULT_SLOTS,
) -> BaseWSGIServer:
    """waitress serving ``app``: API errors in JSON, ``stop_threads`` threads that serve
    stops ahead of the queue (0: stops queue with every other request), and at most
    ``cpu_slots`` other requests running at once (0: no limit but the threads)."""
    if cpu_slots < 0:
        raise ValueError("cpu_slots must be 0 or more")
    if cpu_slots:
        app = CpuSlots(app, cpu_slots, exempt=is_stop_environ)
    dispatcher = StopFirstDispatcher(stop_threads) if stop_threads > 0 else ThreadedTaskDispatcher()
    dispatcher.set_thread_count(threads)
    server = create_server(
        app,
        host=host,
        port=port,
        threads=threads,
        max_request_body_size=MAX_REQUEST_BODY_BYTES,
        _dispatcher=dispatcher,
    )
    # One address, so one server (not waitress's multi-socket one).
    assert isinstance(server, BaseWSGIServer)
    server.channel_class = _JsonErrorChannel
    return server
