"""Is the portal able to do its work? For supervisors, monitoring and the admins' pages.

``GET /healthz`` answers 200 when the web process reaches its database and cache, 503 when
not. It also says when the scheduler (Celery beat queuing the sweep, a worker running it)
last swept for runs to stage and collect: a stopped beat or worker leaves the pages up while
no run reaches its robot, which is the failure an operator most needs to see. That part does
not change the status code: the web process itself is fine, and a load balancer must not
take it out of service for it.
"""

from __future__ import annotations

import logging
import secrets
import time
from typing import Any

from django.conf import settings
from django.core.cache import cache

from core import sql

logger = logging.getLogger(__name__)

SWEEP = "runs-sweep"


def heartbeat_record(name: str, *, now_s: float | None = None) -> None:
    """Note that ``name`` (a periodic task) just ran."""
    cache.set(f"heartbeat:{name}", time.time() if now_s is None else now_s, timeout=None)


def heartbeat_age_s(name: str, *, now_s: float | None = None) -> float | None:
    """Seconds since ``name`` last ran; ``None`` if it never has (or the cache forgot)."""
    at_s = cache.get(f"heartbeat:{name}")
    if not isinstance(at_s, int | float):
        return None
    return max(0.0, (time.time() if now_s is None else now_s) - float(at_s))


def scheduler_stale_after_s() -> float:
    # A few sweeps may be late under load (or while a worker restarts) without alarm.
    return max(30.0, 5.0 * settings.RUN_SWEEP_INTERVAL_S)


def scheduler_status(*, now_s: float | None = None) -> dict[str, Any]:
    age_s = heartbeat_age_s(SWEEP, now_s=now_s)
    return {
        "last_sweep_age_s": None if age_s is None else round(age_s, 1),
        "ok": age_s is not None and age_s <= scheduler_stale_after_s(),
    }


def scheduler_status_or_unknown() -> dict[str, Any]:
    """:func:`scheduler_status`, or "unknown" (not ok) when the cache cannot say: whoever
    asks must keep working when the cache does not."""
    try:
        return scheduler_status()
    except Exception:
        logger.exception("scheduler status unavailable")
        return {"last_sweep_age_s": None, "ok": False}


def health() -> tuple[bool, dict[str, Any]]:
    """Each check as ``"ok"`` or a short error (no internals), and whether the web can work."""
    body: dict[str, Any] = {}
    try:
        sql.ping()
        body["database"] = "ok"
    except Exception as exc:  # any failure is the answer here
        logger.error("health: database unreachable: %s", exc)
        body["database"] = "unreachable"
    try:
        # A key of this probe's own: two probes at once (a load balancer and Prometheus)
        # must not read each other's value and report the cache as broken.
        token = secrets.token_hex(8)
        cache.set(f"health:probe:{token}", token, timeout=30)
        body["cache"] = "ok" if cache.get(f"health:probe:{token}") == token else "not storing"
    except Exception as exc:
        logger.error("health: cache unreachable: %s", exc)
        body["cache"] = "unreachable"
    body["scheduler"] = scheduler_status_or_unknown()  # a cache failure is reported above
    ok = body["database"] == "ok" and body["cache"] == "ok"
    body["status"] = "ok" if ok else "failing"
    return ok, body
