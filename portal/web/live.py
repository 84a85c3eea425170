"""Server-Sent Events for the pages: a run, a robot's console, the calendar.

Async views on the ASGI server: an open stream is a coroutine waiting on the bus
(``core.live``), not a worker thread, so a page left open costs the portal nothing while
nothing happens. Each stream:

- starts with ``retry:`` (how soon the browser reconnects) and an ``open`` event;
- forwards each event of its channels as ``event: <type>`` with the JSON as data;
- sends a comment line every ``KEEPALIVE_S`` so proxies and the browser see it alive;
- ends after ``STREAM_MAX_S`` (the browser reconnects and the login is checked again), or
  when the bus drops — the page then shows "reconnecting", polls, and reconnects.

A bus that cannot be reached answers 503 at once; a WSGI server (no streams there) 204. The
pages read their data once on every (re)connect, so events missed while the stream was down
are never needed.
"""

from __future__ import annotations

import functools
import json
import time
from collections.abc import AsyncIterator, Callable, Coroutine
from typing import Any
from urllib.parse import urlsplit

from django.core.handlers.asgi import ASGIRequest
from django.http import HttpRequest, HttpResponse, JsonResponse, StreamingHttpResponse
from django.http.response import HttpResponseBase
from django.utils.cache import patch_vary_headers

from bookings.models import Resource
from core.live import CALENDAR, LiveUnavailable, robot_channel, run_channel, subscribe
from portal.runs.selectors import runs_visible

StreamView = Callable[..., Coroutine[Any, Any, HttpResponseBase]]

KEEPALIVE_S = 15.0
STREAM_MAX_S = 600.0
RETRY_MS = 2000


def _sse(event: str, data: dict[str, Any]) -> str:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'), default=str)}\n\n"


async def _stream(channels: list[str]) -> HttpResponseBase:
    events = subscribe(channels, idle_s=KEEPALIVE_S)
    try:
        await anext(events)  # subscribed (or the bus is down: 503 now, not a dead stream)
    except LiveUnavailable:
        await events.aclose()
        return JsonResponse(
            {"error": "live_unavailable", "detail": "Live updates are down; the page polls."},
            status=503,
        )

    async def body() -> AsyncIterator[str]:
        deadline = time.monotonic() + STREAM_MAX_S
        try:
            yield f"retry: {RETRY_MS}\n\n" + _sse("open", {"channels": channels})
            async for event in events:
                if time.monotonic() > deadline:
                    return
                if event is None:
                    yield ": keepalive\n\n"
                else:
                    yield _sse(str(event.get("type") or "message"), event)
        except LiveUnavailable:
            return  # the bus dropped: the browser reconnects (and polls meanwhile)
        finally:
            await events.aclose()

    response = StreamingHttpResponse(body(), content_type="text/event-stream")
    response["Cache-Control"] = "no-cache"
    response["X-Accel-Buffering"] = "no"  # a buffering proxy would hold the events back
    return response


def _no_stream() -> HttpResponseBase:
    """Under a WSGI server (a test's live server, a WSGI deployment) a stream would hold its
    thread for good. 204 tells the browser not to reconnect; the page polls instead."""
    return HttpResponse(status=204)


def _same_host(view: StreamView) -> StreamView:
    """Let the pages of this host follow a stream served on another port of it (the ASGI
    server beside the WSGI one: ``LIVE_STREAM_PORT``). A browser sends the session cookie to
    another port of the same host only for a credentialed request, and reads the answer only if
    it names the page's origin; any other origin gets no such header and reads nothing."""

    @functools.wraps(view)
    async def wrapped(request: HttpRequest, *args: Any, **kwargs: Any) -> HttpResponseBase:
        response = await view(request, *args, **kwargs)
        origin = request.headers.get("Origin", "")
        host = request.get_host().rsplit(":", 1)[0].strip("[]")
        if origin and urlsplit(origin).hostname == host:
            response["Access-Control-Allow-Origin"] = origin
            response["Access-Control-Allow-Credentials"] = "true"
        patch_vary_headers(response, ("Origin",))
        return response

    return wrapped


def _denied() -> HttpResponseBase:
    # A stream gets no login redirect: the page that opened it handles 403 by polling.
    return JsonResponse({"error": "forbidden", "detail": "Log in to follow this."}, status=403)


@_same_host
async def run_stream(request: HttpRequest, pk: int) -> HttpResponseBase:
    """State changes and new samples of one run the user may see."""
    if not isinstance(request, ASGIRequest):
        return _no_stream()
    user = await request.auser()
    if not user.is_authenticated:
        return _denied()
    if not await runs_visible(user=user).filter(pk=pk).aexists():
        return JsonResponse({"error": "not_found", "detail": "No such run."}, status=404)
    return await _stream([run_channel(pk)])


@_same_host
async def robot_stream(request: HttpRequest, name: str) -> HttpResponseBase:
    """A robot's status as the health check reads it, and its hold (admins)."""
    if not isinstance(request, ASGIRequest):
        return _no_stream()
    user = await request.auser()
    if not user.is_authenticated or not getattr(user, "is_testbed_admin", False):
        return _denied()
    if not await Resource.objects.filter(name=name, kind="mobile").aexists():
        return JsonResponse({"error": "not_found", "detail": "No such robot."}, status=404)
    return await _stream([robot_channel(name)])


@_same_host
async def calendar_stream(request: HttpRequest) -> HttpResponseBase:
    """Bookings and maintenance changed (the calendar reads them again), robots held."""
    if not isinstance(request, ASGIRequest):
        return _no_stream()
    user = await request.auser()
    if not user.is_authenticated:
        return _denied()
    return await _stream([CALENDAR])
