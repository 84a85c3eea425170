"""``python -m bookings.scheduler.standin``: the stand-in broker's process, served with
waitress until SIGTERM or SIGINT."""

from __future__ import annotations

import logging
import os
import signal
import sqlite3
import sys
import types
from collections.abc import Sequence

from waitress.server import create_server

from bookings.scheduler.standin.app import MAX_BODY_BYTES, close_app, create_app
from bookings.scheduler.standin.config import ConfigError, build_parser, config_from

# Named after the package, not the module: every log line of the stand-in carries one name.
logger = logging.getLogger("bookings.scheduler.standin")


class _Stop(SystemExit):
    """Raised in the main thread by the signal handler; waitress stops serving on it."""


def _raise_stop(signum: int, frame: types.FrameType | None) -> None:
    raise _Stop(0)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        stream=sys.stderr,
        level=args.log_level.upper(),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        config = config_from(args, os.environ)
        app = create_app(config)
    except (ConfigError, sqlite3.Error, OSError) as exc:
        print(f"scheduler stand-in: configuration error: {exc}", file=sys.stderr)
        return 2
    try:
        server = create_server(
            app,
            host=args.host,
            port=args.port,
            threads=args.threads,
            max_request_body_size=MAX_BODY_BYTES,
        )
    except OSError as exc:
        logger.error("cannot listen on %s:%s: %s", args.host, args.port, exc)
        close_app(app)
        return 1
    port = getattr(server, "effective_port", args.port)
    logger.info(
        "scheduler stand-in listening on http://%s:%s (conflicts as %s, granularity %d s, "
        "empty list as %s, auth %s, %d nodes, leases in %s%s)",
        args.host,
        port,
        config.conflict_as,
        config.granularity_s,
        "404" if config.empty_as_404 else "[]",
        "on" if config.token else "off",
        len(config.nodes),
        config.db_path,
        ", test control ON" if config.test_control else "",
    )
    previous = {sig: signal.signal(sig, _raise_stop) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        server.run()
    except _Stop:
        pass
    finally:
        for sig in previous:
            signal.signal(sig, signal.SIG_IGN)
        server.close()
        close_app(app)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    logger.info("scheduler stand-in stopped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
