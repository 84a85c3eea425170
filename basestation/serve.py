"""``amazing-agent`` / ``python -m basestation``: serve the agent with waitress."""

from __future__ import annotations

import argparse
import gc
import json
import logging
import os
import signal
import sys
import threading
import types
from collections.abc import Callable, Iterable
from typing import Any

from waitress.channel import HTTPChannel
from waitress.server import BaseWSGIServer, create_server
from waitress.task import ErrorTask, Task, WSGITask
from waitress.utilities import Error

from basestation.api.limits import too_large_detail
from basestation.app import MAX_BODY_BYTES, create_app
from basestation.backup import AgentRunning, data_dir_lock
from basestation.config import AgentConfig, ConfigError
from basestation.contract import STOP_PATH, STOP_PORT_OFFSET
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
# The stop's own listener: one stop served while a second waits is plenty (a stop latches in
# a few milliseconds), and every thread more would compete for the interpreter lock.
STOP_THREADS = 2

WSGIApp = Callable[[dict[str, Any], Callable[..., Any]], Iterable[bytes]]


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
    if request.error.code == 413 and request.command == "POST" and request.path == STOP_PATH:
        request.error = None
        request.body_rcv = None
        request.headers["CONTENT_LENGTH"] = "0"
        task = WSGITask(channel, request)
        task.close_on_finish = True  # the rest of the body is still on its way: hang up
        return task
    return _JsonErrorTask(channel, request)


class _JsonErrorChannel(HTTPChannel):
    error_task_class = staticmethod(_error_task)  # type: ignore[assignment]


def stop_only(app: WSGIApp) -> WSGIApp:
    """The application as the stop's listener serves it: ``/api/v1/stop`` and nothing else,
    so that no other request can queue on it."""
    refusal = json.dumps(
        {"error": "not_found", "detail": f"This port serves only POST {STOP_PATH}."}
    ).encode()

    def serve(environ: dict[str, Any], start_response: Callable[..., Any]) -> Iterable[bytes]:
        if environ.get("PATH_INFO") == STOP_PATH:
            return app(environ, start_response)
        start_response(
            "404 Not Found",
            [("Content-Type", "application/json"), ("Content-Length", str(len(refusal)))],
        )
        return [refusal]

    return serve


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
        "--stop-port",
        type=int,
        default=None,
        help="TCP port of the listener that serves only POST /api/v1/stop, with threads of "
        f"its own (default: --port + {STOP_PORT_OFFSET}; 0 picks a free one)",
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
    if args.stop_port is None:
        args.stop_port = 0 if args.port == 0 else args.port + STOP_PORT_OFFSET
    try:
        server = _server(app, args.host, args.port, args.threads)
        # The stop's own socket, accept queue and threads: a stop never waits behind the
        # API's readers (docs/basestation.md "The emergency stop's listener").
        stop_server = _server(stop_only(app), args.host, args.stop_port, STOP_THREADS)
    except OSError as exc:
        logger.error("cannot listen on %s: %s", args.host, exc)
        runtime.close()
        return 1
    port = getattr(server, "effective_port", args.port)
    stop_port = getattr(stop_server, "effective_port", args.stop_port)
    threading.Thread(target=stop_server.run, name="stop-listener", daemon=True).start()
    logger.info(
        "emergency stop served apart on http://%s:%s (POST %s only)",
        args.host,
        stop_port,
        STOP_PATH,
    )
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
        stop_server.close()
        server.close()
        runtime.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    logger.info("agent stopped")
    return 0


def _server(app: WSGIApp, host: str, port: int, threads: int) -> BaseWSGIServer:
    server = create_server(
        app, host=host, port=port, threads=threads, max_request_body_size=MAX_REQUEST_BODY_BYTES
    )
    # One address, so one server (not waitress's multi-socket one).
    assert isinstance(server, BaseWSGIServer)
    server.channel_class = _JsonErrorChannel
    return server
