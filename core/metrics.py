"""Prometheus metrics of the portal: HTTP rate and latency per view, and ``/metrics``.

The web server runs several processes (``portal/serve.py``); prometheus-client's
multiprocess mode adds their counts up when ``PROMETHEUS_MULTIPROC_DIR`` names a folder the
processes share (``portal/serve.py`` sets one and empties it at start). Without it
(a single process, the tests) the process's own registry is served.

``/metrics`` answers only with ``Authorization: Bearer <METRICS_TOKEN>`` (Prometheus's
``authorization: {credentials_file: …}``), and is absent (404) while no token is configured.
"""

from __future__ import annotations

import hmac
import os
import time
from collections.abc import Callable, Iterable, Iterator

from django.conf import settings
from django.http import Http404, HttpRequest, HttpResponse
from prometheus_client import (
    CONTENT_TYPE_LATEST,
    REGISTRY,
    CollectorRegistry,
    Counter,
    Histogram,
    generate_latest,
    multiprocess,
)
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector

REQUESTS = Counter(
    "amazing_http_requests",
    "HTTP requests answered, by view, method and status class.",
    ["view", "method", "status"],
)
LATENCY = Histogram(
    "amazing_http_request_duration_seconds",
    "Time to answer, by view (streams and downloads included).",
    ["view"],
    buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.2, 0.5, 1.0, 2.5, 5.0, 10.0),
)


# The method label's values: a client may send any token as its method, and each new label
# value is a new series kept for good, so the rest count as "other".
HTTP_METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})


def method_label(method: str | None) -> str:
    return method if method in HTTP_METHODS else "other"


class RequestMetricsMiddleware:
    """Counts and times every answer by the view that gave it (its URL name: bounded, unlike
    paths with ids in them); unmatched paths count as one ``unmatched`` view."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        started_s = time.perf_counter()
        response = self.get_response(request)
        match = request.resolver_match
        view = (match.view_name or "unnamed") if match is not None else "unmatched"
        LATENCY.labels(view).observe(time.perf_counter() - started_s)
        status = f"{response.status_code // 100}xx"
        REQUESTS.labels(view, method_label(request.method), status).inc()
        return response


def _authorized(request: HttpRequest) -> bool:
    token = settings.METRICS_TOKEN
    if not token:
        raise Http404("metrics are off: set METRICS_TOKEN")
    given = request.headers.get("Authorization", "")
    return hmac.compare_digest(given.encode(), f"Bearer {token}".encode())


def metrics_response(request: HttpRequest, collectors: Iterable[Collector]) -> HttpResponse:
    """The exposition of the HTTP metrics (all processes') and of ``collectors``."""
    if not _authorized(request):
        response = HttpResponse("a bearer token is required\n", status=401)
        response["WWW-Authenticate"] = 'Bearer realm="metrics"'
        return response
    registry: CollectorRegistry
    if os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
        registry = CollectorRegistry(auto_describe=False)
        multiprocess.MultiProcessCollector(registry)
    else:
        registry = CollectorRegistry(auto_describe=False)
        registry.register(_Process())
    for collector in collectors:
        registry.register(collector)
    return HttpResponse(generate_latest(registry), content_type=CONTENT_TYPE_LATEST)


class _Process(Collector):
    """This process's own metrics (one process: no multiprocess folder)."""

    def collect(self) -> Iterator[Metric]:
        yield from REGISTRY.collect()
