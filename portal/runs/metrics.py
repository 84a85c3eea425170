"""``/metrics``: the system's state for Prometheus, read at scrape time from the database and
the robots' last health checks, beside the web server's HTTP metrics (``core/metrics.py``).

Runs by state, how far behind the collection of each running run is, robots held out of
booking, each robot's battery, e-stop, radio link and reachability, the testbed scheduler
link's last success and error, and the counters every process adds to (staging failures,
scheduler-link errors, health holds: ``core/audit/counters.py``, kept in the database, so
the workers' counts reach this scrape). docs/operations.md lists the alerts to set.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

from django.db.models import Count, OuterRef, Subquery
from django.http import HttpRequest, HttpResponse
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from bookings.choices import ResourceKind
from bookings.models import Resource, SchedulerLink
from core.audit.counters import COUNTERS, event_counts
from core.events.metrics import EventsCollector
from core.metrics import metrics_response
from portal.runs.models import Run, Sample
from portal.runs.services.health import robot_health_cached
from portal.runs.states import RunState


def _gauge(name: str, doc: str, labels: list[str]) -> GaugeMetricFamily:
    return GaugeMetricFamily(f"amazing_{name}", doc, labels=labels)


class SystemCollector(Collector):
    def __init__(self, now_s: float | None = None) -> None:
        self.now_s = now_s

    def collect(self) -> Iterator[Any]:
        now_s = time.time() if self.now_s is None else self.now_s
        runs = _gauge("runs", "Runs by state.", ["state"])
        counts = dict(Run.objects.values_list("state").annotate(n=Count("id")).order_by())
        for state in RunState.values:
            runs.add_metric([state], counts.get(state, 0))
        yield runs

        lag = _gauge(
            "run_collection_lag_seconds",
            "A running run: now minus the time of its newest stored sample.",
            ["run", "resource"],
        )
        newest = Sample.objects.filter(run=OuterRef("pk")).order_by("-seq").values("t")[:1]
        running = Run.objects.filter(state=RunState.RUNNING).annotate(newest_t=Subquery(newest))
        for run_id, robot_name, newest_t, start_at in running.values_list(
            "pk", "resource__name", "newest_t", "start_at"
        ):
            since_s = (newest_t or start_at).timestamp()
            lag.add_metric([str(run_id), robot_name or ""], max(0.0, now_s - since_s))
        yield lag

        held = _gauge("resource_held", "1 while the health check holds the resource.", ["resource"])
        battery = _gauge(
            "robot_battery_volts", "The robot's battery at its last check.", ["resource"]
        )
        estop = _gauge(
            "robot_estop_latched", "1 while the robot's e-stop is latched.", ["resource"]
        )
        link = _gauge("robot_link_up", "1 while the robot answers its base station.", ["resource"])
        reachable = _gauge(
            "robot_agent_reachable", "1 while the robot's agent answers.", ["resource"]
        )
        checked = _gauge(
            "robot_health_age_seconds", "Since the robot was last checked.", ["resource"]
        )
        for resource in Resource.objects.all():
            held.add_metric([resource.name], 1.0 if resource.hold_reason else 0.0)
            if resource.kind != ResourceKind.MOBILE:
                continue
            health = robot_health_cached(name=resource.name)
            if health is None:
                continue
            checked.add_metric([resource.name], max(0.0, now_s - health.checked_at_s))
            reachable.add_metric([resource.name], 1.0 if health.reachable else 0.0)
            status = health.status or {}
            if isinstance(status.get("battery_v"), int | float):
                battery.add_metric([resource.name], float(status["battery_v"]))
            if isinstance(status.get("estop"), dict):
                estop.add_metric([resource.name], 1.0 if status["estop"].get("latched") else 0.0)
            if isinstance(status.get("link"), dict):
                link.add_metric(
                    [resource.name], 1.0 if status["link"].get("state") == "up" else 0.0
                )
        yield from (held, battery, estop, link, reachable, checked)

        yield from _counters()

        scheduler = SchedulerLink.objects.first()
        if scheduler is not None:
            for name, at in (
                ("scheduler_last_success_timestamp_seconds", scheduler.last_success_at),
                ("scheduler_last_error_timestamp_seconds", scheduler.last_error_at),
            ):
                if at is not None:
                    yield GaugeMetricFamily(
                        f"amazing_{name}",
                        "The testbed scheduler link's sweeps.",
                        value=at.timestamp(),
                    )


def _counters() -> Iterator[CounterMetricFamily]:
    counted: dict[str, list[tuple[dict[str, str], int]]] = {name: [] for name in COUNTERS}
    for count in event_counts():
        if count.name in counted:
            counted[count.name].append((count.labels, count.value))
    for name, values in counted.items():
        label_names = sorted({key for labels, _ in values for key in labels})
        family = CounterMetricFamily(f"amazing_{name}", COUNTERS[name], labels=label_names)
        if not values and not label_names:
            family.add_metric([], 0)  # an unlabelled counter is there from the start
        for labels, value in values:
            family.add_metric([labels.get(key, "") for key in label_names], value)
        yield family


def metrics_view(request: HttpRequest) -> HttpResponse:
    return metrics_response(request, [SystemCollector(), EventsCollector()])
