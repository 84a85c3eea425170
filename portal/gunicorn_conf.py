"""The WSGI server's settings (``gunicorn -c python:portal.gunicorn_conf``): pages and API.

Threads in a few processes: a request is plain synchronous Django on a thread of its own, with
no bridge between an event loop and the views, and a process per core uses both cores. The
numbers come from the portal's settings (``WEB_WORKERS``, ``WEB_THREADS``), so the settings
are checked before any worker starts. The live streams are the ASGI server's
(``portal/processes.py`` ``streams_process``): a stream here would hold a thread for good.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from portal import settings

worker_class = "gthread"
workers = settings.WEB_WORKERS
threads = settings.WEB_THREADS
# A request still running this long is a fault (the longest downloads stream in well under it).
timeout = 120
graceful_timeout = 10
# TLS ends at the proxy in front; it says who the client is and how it came.
forwarded_allow_ips = "*"
# In production the server's own lines (start, workers, errors) are JSON like the portal's.
logconfig_dict = settings.LOGGING if settings.LOG_JSON else {}

# Prometheus: the processes' HTTP metrics add up in one folder of this server's own, emptied
# at its start (core/metrics.py). Set before any worker imports prometheus-client.
_metrics_dir = Path(
    os.environ.setdefault(
        "PROMETHEUS_MULTIPROC_DIR", str(settings.VAR_DIR / "metrics" / f"web-{os.getpid()}")
    )
)

# Only now: prometheus-client picks its multiprocess storage when first imported, and the
# workers inherit the module from this process.
from prometheus_client import multiprocess  # noqa: E402


def on_starting(server: Any) -> None:
    shutil.rmtree(_metrics_dir, ignore_errors=True)
    _metrics_dir.mkdir(parents=True, exist_ok=True)


def child_exit(server: Any, worker: Any) -> None:
    multiprocess.mark_process_dead(worker.pid)
