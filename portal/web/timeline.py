"""The resource timeline: every robot and fixed node as a row, time across.

The page draws what ``calendar/events.json`` lists (bookings, maintenance, the testbed
scheduler's leases) on the rows they hold, and books through the REST API, as the week view
does; this module only hands the page its rows.
"""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse
from django.shortcuts import render
from django.utils import timezone

from bookings.choices import ResourceKind
from bookings.models import Resource
from bookings.quotas import quota_summary
from bookings.selectors import resources_bookable
from portal.experiments.selectors import experiments_visible

# The rows' groups, in the order they are drawn.
ROW_GROUPS = (
    (ResourceKind.MOBILE, "group-robots", "Robots"),
    (ResourceKind.FIXED, "group-fixed", "Fixed nodes"),
)


def timeline_rows(resources: list[Resource]) -> list[dict[str, Any]]:
    """The resources as nested rows (a group each for robots and fixed nodes), with what the
    page needs to draw a health hold and to say when approval is needed."""
    rows = []
    for kind, group_id, title in ROW_GROUPS:
        children = [
            {
                "id": r.name,
                "title": r.name,
                "extendedProps": {
                    "mobile": r.is_mobile,
                    "needs_approval": r.requires_approval,
                    "hold_reason": r.hold_reason if r.held_at else "",
                    "held_at": r.held_at.isoformat() if r.held_at else None,
                },
            }
            for r in resources
            if r.kind == kind
        ]
        if children:
            rows.append({"id": group_id, "title": title, "children": children, "extendedProps": {}})
    return rows


@login_required
def timeline_page(request: HttpRequest) -> HttpResponse:
    user: Any = request.user
    resources = list(resources_bookable().order_by("name"))
    return render(
        request,
        "web/timeline.html",
        {
            "rows": timeline_rows(resources),
            "experiments": experiments_visible(user=user).filter(owner=user).order_by("title"),
            "quota": quota_summary(user=user, now=timezone.now()),
            "snap_min": settings.TIMELINE_SNAP_MIN,
        },
    )
