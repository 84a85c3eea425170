"""The pages and the API on the WSGI server: ``python -m portal.serve --bind HOST:PORT``.

Granian (a WSGI server whose HTTP side is compiled) runs ``WEB_WORKERS`` processes (a process
per core by default) of ``WEB_THREADS`` threads each: a request is plain synchronous Django on
a thread, with no bridge between an event loop and the views, and the processes use every
core. Measured against gunicorn's threaded workers with the same application and requests,
the server's part of a request costs a third of the instructions (``docs/performance-history.md``).
The live streams are the ASGI server's (``portal/processes.py`` ``streams_process``): a stream
here would hold a thread for good.

The numbers come from the portal's settings, so the settings are checked before any worker
starts. Prometheus's multiprocess folder (``core/metrics.py``) is this server's own and is
emptied here, once, before the workers (forked from this process) import prometheus-client:
nothing this module imports loads prometheus-client (a test checks), so the workers do not
inherit one that chose its storage before the folder was set.
"""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path
from typing import Any

from granian import Granian
from granian.constants import Interfaces
from granian.log import LogLevels

from portal import settings

APPLICATION = "portal.wsgi:application"
# On a stop or a restart, requests in flight get this long before their worker is killed.
WORKERS_KILL_TIMEOUT_S = 10


def metrics_dir() -> Path:
    """The folder the workers' HTTP metrics add up in: the environment's, or one of this
    server's own under ``var/`` (set now, inherited by the workers)."""
    return Path(
        os.environ.setdefault(
            "PROMETHEUS_MULTIPROC_DIR", str(settings.VAR_DIR / "metrics" / f"web-{os.getpid()}")
        )
    )


def server_options(argv: list[str] | None = None) -> dict[str, Any]:
    """Granian's settings for this command line and the portal's settings."""
    parser = argparse.ArgumentParser(prog="python -m portal.serve", description=__doc__)
    parser.add_argument("--bind", default="127.0.0.1:8000", help="HOST:PORT to listen on")
    parser.add_argument(
        "--access-log", action="store_true", help="the server's own line per request"
    )
    args = parser.parse_args(argv)
    host, _, port = args.bind.rpartition(":")
    if not host or not port.isdigit():
        parser.error(f"--bind {args.bind!r}: give HOST:PORT")
    return {
        "target": APPLICATION,
        "address": host.strip("[]"),
        "port": int(port),
        "workers": settings.WEB_WORKERS,
        "blocking_threads": settings.WEB_THREADS,
        # A worker that dies is started again; the others keep serving meanwhile.
        "respawn_failed_workers": True,
        "workers_kill_timeout": WORKERS_KILL_TIMEOUT_S,
        # In production the server's own lines (start, workers, errors) are JSON like the
        # portal's; the portal writes its own access line (core.http.RequestIdMiddleware).
        "log_dictconfig": settings.LOGGING if settings.LOG_JSON else None,
        "log_access": args.access_log,
    }


def main(argv: list[str] | None = None) -> None:
    options = server_options(argv)
    folder = metrics_dir()
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True, exist_ok=True)

    Granian(
        interface=Interfaces.WSGI, websockets=False, log_level=LogLevels.info, **options
    ).serve()


if __name__ == "__main__":
    main()
