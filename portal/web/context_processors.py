from __future__ import annotations

import logging
from typing import Any

from django.conf import settings
from django.http import HttpRequest

from portal.health import scheduler_status

logger = logging.getLogger(__name__)


def testbed(request: HttpRequest) -> dict[str, Any]:
    context: dict[str, Any] = {"TESTBED_TIME_ZONE": settings.TIME_ZONE}
    user = getattr(request, "user", None)
    if user is not None and user.is_authenticated and user.is_staff:
        from bookings.models import Resource

        # Admins get a console link per robot.
        context["MOBILE_NODES"] = list(
            Resource.objects.filter(kind="mobile").values_list("name", flat=True)
        )
        context["SCHEDULER"] = _scheduler()
    return context


def _scheduler() -> dict[str, Any]:
    """The scheduler's state for the admins' warning; a cache that fails says "unknown"."""
    try:
        return scheduler_status()
    except Exception:  # a page must not fail because the cache does
        logger.exception("scheduler status unavailable")
        return {"last_sweep_age_s": None, "ok": False}
