"""The roof map's data for the pages (run page, robot console): the robot's rail as its agent
draws it (``portal/runs/roof.py``).

The page asks once when it opens. An agent that cannot be asked is part of what the page
shows ("the map is not available: …"), so the answer is 200 either way, with ``available``
saying which; the REST API (``/api/v1/resources/{name}/rail/``) answers 503 instead.
"""

from __future__ import annotations

from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, JsonResponse
from django.shortcuts import get_object_or_404

from bookings.models import Resource
from core.errors import DomainError
from portal.runs.roof import rail_drawing


@login_required
def rail_json(request: HttpRequest, name: str) -> JsonResponse:
    resource = get_object_or_404(Resource, name=name, kind="mobile")
    try:
        drawing = rail_drawing(resource=resource)
    except DomainError as exc:
        return JsonResponse({"available": False, "detail": exc.message})
    return JsonResponse({"available": True, "robot": resource.name, **drawing})
