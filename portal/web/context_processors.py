from __future__ import annotations

from typing import Any

from django.conf import settings
from django.http import HttpRequest

from bookings.choices import ResourceKind
from bookings.models import Resource
from core.health import scheduler_status_or_unknown


def testbed(request: HttpRequest) -> dict[str, Any]:
    context: dict[str, Any] = {
        "TESTBED_TIME_ZONE": settings.TIME_ZONE,
        "LIVE_STREAM_PORT": settings.LIVE_STREAM_PORT,
    }
    user = getattr(request, "user", None)
    if user is not None and user.is_authenticated and user.is_testbed_admin:
        # Admins get a console link per robot.
        context["MOBILE_NODES"] = list(
            Resource.objects.filter(kind=ResourceKind.MOBILE).values_list("name", flat=True)
        )
        context["SCHEDULER"] = scheduler_status_or_unknown()
    return context
