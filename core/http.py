"""Response headers every page and answer carries, beside Django's own and the CSP's, and
the request id each request runs under."""

from __future__ import annotations

import ipaddress
import logging
import time
from collections.abc import Callable
from typing import Any

from django.conf import settings
from django.http import HttpRequest, HttpResponse

from basestation.contract import REQUEST_ID_HEADER
from core.logs import request_id_bound

access_log = logging.getLogger("portal.access")


def client_address(request: HttpRequest | Any) -> str | None:
    """The client's address: the one place that says who is asking, for the sign-in limits
    (allauth's ``ALLAUTH_TRUSTED_PROXY_COUNT`` is the same count and rule; a test holds the
    two to the same cases), the API throttles, the audit rows and the access log.

    With ``TRUSTED_PROXY_COUNT`` = 0 it is the peer's address (``REMOTE_ADDR``) and
    ``X-Forwarded-For`` is ignored. With N proxies of ours in front, each appends the address
    it saw, so the client is the N-th entry from the right; whatever stands left of it the
    client wrote itself. A request that came without the header (a probe inside the
    deployment's network) is its peer's. Not an address: None.
    """
    meta = getattr(request, "META", {})
    address = meta.get("REMOTE_ADDR")
    count = settings.TRUSTED_PROXY_COUNT
    forwarded = meta.get("HTTP_X_FORWARDED_FOR")
    if count > 0 and forwarded:
        entries = forwarded.split(",")
        address = entries[-min(count, len(entries))]
    if not address:
        return None
    try:
        return str(ipaddress.ip_address(address.strip().strip("[]")))
    except ValueError:
        return None


# URL arguments that are secrets (a calendar feed's token, its only key): the access line
# writes them as REDACTED. deploy/nginx.conf's log format does the same for the proxy's log.
SECRET_URL_ARGUMENTS = frozenset({"token"})
REDACTED = "[redacted]"


def loggable_path(request: HttpRequest) -> str:
    """The request's path with any secret URL argument replaced by ``REDACTED``."""
    path = request.path
    match = request.resolver_match
    if match is not None:
        for name, value in match.kwargs.items():
            if name in SECRET_URL_ARGUMENTS and isinstance(value, str) and value:
                path = path.replace(value, REDACTED)
    return path


class RequestIdMiddleware:
    """Runs each request under a request id: the caller's ``X-Request-ID`` (a proxy's) when it
    is a plain token, else a new one. Every log line of the request names it, the agent
    calls made for it carry it, and the answer returns it. With ``ACCESS_LOG`` on (production)
    one line per request says what was answered, how fast."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response
        self.access_log = settings.ACCESS_LOG

    def __call__(self, request: HttpRequest) -> HttpResponse:
        started_s = time.perf_counter()
        with request_id_bound(request.headers.get(REQUEST_ID_HEADER)) as request_id:
            response = self.get_response(request)
            response[REQUEST_ID_HEADER] = request_id
            if self.access_log:
                match = request.resolver_match
                path = loggable_path(request)
                access_log.info(
                    "%s %s %s",
                    request.method,
                    path,
                    response.status_code,
                    extra={
                        "method": request.method,
                        "path": path,
                        "status": response.status_code,
                        "view": match.view_name if match is not None else None,
                        "duration_ms": round((time.perf_counter() - started_s) * 1000, 1),
                        "client": client_address(request),
                    },
                )
        return response


class PermissionsPolicyMiddleware:
    """``Permissions-Policy``: the browser features no page of the portal uses are off, so a
    script that got in anyway cannot reach the camera, the microphone or the location."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response
        self.header = ", ".join(f"{feature}=()" for feature in settings.PERMISSIONS_POLICY_OFF)

    def __call__(self, request: HttpRequest) -> HttpResponse:
        response = self.get_response(request)
        response.headers.setdefault("Permissions-Policy", self.header)
        return response
