"""The calendar pages: the week view of one resource, the entries both calendars draw
(``calendar/events.json``), and the iCalendar feeds with their page.

Times a person types or a feed reader asks for are the testbed's wall clock, read by
``core.wall_clock`` (the repeated hour is its first occurrence, the missing one refused).
"""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import Any
from zoneinfo import ZoneInfo

from django.conf import settings
from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.core.exceptions import BadRequest
from django.http import HttpRequest, HttpResponse, JsonResponse
from django.shortcuts import get_object_or_404, render
from django.urls import reverse
from django.utils import timezone
from django.utils.dateparse import parse_datetime

from bookings.calendar import (
    calendar_entries,
    calendar_feed_of,
    calendar_feed_renew,
    calendar_feed_user,
    ical_document,
)
from bookings.models import Resource
from bookings.quotas import quota_summary
from bookings.selectors import resources_bookable
from core.wall_clock import NonexistentLocalTime, local_instant
from portal.experiments.selectors import experiments_visible
from portal.runs.selectors import (
    run_ids_by_reservation,
)
from portal.runs.services.health import robots_held
from portal.web.views import _user

# What a calendar feed holds: a month back, a year ahead.
FEED_PAST = timedelta(days=31)
FEED_FUTURE = timedelta(days=366)


@login_required
def calendar_page(request: HttpRequest) -> HttpResponse:
    user = _user(request)
    return render(
        request,
        "web/calendar.html",
        {
            "resources": resources_bookable(),
            "held": robots_held(),
            "experiments": experiments_visible(user=user).filter(owner=user),
            "quota": quota_summary(user=user, now=timezone.now()),
        },
    )


def _range(request: HttpRequest) -> tuple[datetime, datetime]:
    try:
        start = parse_datetime(request.GET.get("start", ""))
        end = parse_datetime(request.GET.get("end", ""))
    except ValueError:
        start = end = None
    if start is None or end is None or end <= start or end - start > timedelta(days=62):
        raise BadRequest("Give start and end (ISO 8601), at most 62 days apart.")
    zone = ZoneInfo(settings.TIME_ZONE)
    try:
        start = local_instant(start, zone) if timezone.is_naive(start) else start
        end = local_instant(end, zone) if timezone.is_naive(end) else end
    except NonexistentLocalTime as exc:
        raise BadRequest(str(exc)) from None
    return start, end


@login_required
def calendar_events(request: HttpRequest) -> JsonResponse:
    """Events for the calendar page: own bookings in full, others' as busy, maintenance windows.

    Each event's kind is its class (``calendar-<kind>``), which app.css colours."""
    start, end = _range(request)
    resource = None
    if request.GET.get("resource"):
        resource = get_object_or_404(Resource, name=request.GET["resource"])
    entries = calendar_entries(
        viewer=_user(request), start_at=start, end_at=end, resource=resource, now=timezone.now()
    )
    runs = run_ids_by_reservation([e.reservation_id for e in entries if e.reservation_id])
    events = []
    for e in entries:
        run_id = runs.get(e.reservation_id) if e.reservation_id else None
        event: dict[str, Any] = {
            "id": e.uid,
            "title": e.title,
            "start": e.start_at.isoformat(),
            "end": e.end_at.isoformat(),
            "editable": e.editable,
            "classNames": [f"calendar-{e.kind}"],
            "extendedProps": {
                "kind": e.kind,
                "reservation": e.reservation_id,
                "state": e.state,
                "resources": list(e.resources),
                "url": reverse("run", args=[run_id]) if run_id else "",
            },
        }
        if e.kind == "blackout":
            event["display"] = "background"
        events.append(event)
    return JsonResponse(events, safe=False)


@login_required
def calendar_feeds(request: HttpRequest) -> HttpResponse:
    """The feed addresses, shown only when made (only the secret's digest is kept): on the
    first visit, and after "make new addresses"."""
    user = _user(request)
    feed = calendar_feed_of(user)
    token: str | None = None
    if request.method == "POST" or feed is None:
        token = calendar_feed_renew(user=user)
        if feed is not None:
            messages.success(request, "New feed addresses made; the old ones no longer work.")
    base = request.build_absolute_uri("/")[:-1]
    context: dict[str, Any] = {"made_at": feed.created_at if feed is not None else None}
    if token is not None:
        context["personal"] = base + reverse("ical-personal", args=[token])
        context["per_resource"] = [
            (r.name, base + reverse("ical-resource", args=[token, r.name]))
            for r in resources_bookable()
        ]
    response = render(request, "web/feeds.html", context)
    # The page holds the secret: no cache keeps it.
    response["Cache-Control"] = "no-store"
    return response


def _feed_not_found() -> HttpResponse:
    response = HttpResponse(
        "No such feed (it may have been renewed, or the resource has another name).\n",
        status=404,
        content_type="text/plain",
    )
    # Django logs every 4xx with its path, and this path holds a secret (a revoked one, or
    # someone's guess): the access line (core/http.py) writes the path redacted instead.
    response._has_been_logged = True  # type: ignore[attr-defined]
    return response


def _ical_response(entries: list[Any], name: str) -> HttpResponse:
    body = ical_document(entries, name=name, stamp=timezone.now())
    response = HttpResponse(body, content_type="text/calendar; charset=utf-8")
    response["Cache-Control"] = "private, max-age=300"
    return response


def ical_personal(request: HttpRequest, token: str) -> HttpResponse:
    user = calendar_feed_user(token)
    if user is None:
        return _feed_not_found()
    now = timezone.now()
    entries = calendar_entries(
        viewer=user, start_at=now - FEED_PAST, end_at=now + FEED_FUTURE, now=now, only_own=True
    )
    return _ical_response(entries, f"AMazING: {user.get_username()}")


def ical_resource(request: HttpRequest, token: str, name: str) -> HttpResponse:
    user = calendar_feed_user(token)
    resource = Resource.objects.filter(name=name).first()
    if user is None or resource is None:
        return _feed_not_found()
    now = timezone.now()
    entries = calendar_entries(
        viewer=user, start_at=now - FEED_PAST, end_at=now + FEED_FUTURE, resource=resource, now=now
    )
    return _ical_response(entries, f"AMazING: {resource.name}")
