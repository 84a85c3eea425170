from __future__ import annotations

from typing import Any

from django.conf import settings
from django.http import HttpRequest


def testbed(request: HttpRequest) -> dict[str, Any]:
    return {"TESTBED_TIME_ZONE": settings.TIME_ZONE}
