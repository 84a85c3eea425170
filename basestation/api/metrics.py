"""``GET /api/v1/metrics``: the base station in Prometheus's text format, for alerting.

The same facts as ``GET /status`` (one document, read at scrape time), as metrics an operator
can alert on: the control loop's ticks, lateness and missed ticks, the loop process's restarts,
battery, e-stop, radio link, clock sync, disk and the faults that keep a run from starting.
Behind the agent's bearer token like the rest of ``/api/v1`` (Prometheus sends it with
``authorization: {credentials_file: …}``). docs/operations.md lists the alerts to set.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from flask import Blueprint, Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, InfoMetricFamily
from prometheus_client.registry import Collector

from basestation.api.status import status_document

bp = Blueprint("metrics", __name__)
PREFIX = "amazing_agent"


def _flag(value: object) -> float:
    return 1.0 if value else 0.0


def _gauge(name: str, doc: str, value: float | None) -> Iterator[GaugeMetricFamily]:
    """A gauge, or nothing while the agent does not know the value (no sample is no lie)."""
    if value is not None:
        yield GaugeMetricFamily(f"{PREFIX}_{name}", doc, value=float(value))


def _counter(name: str, doc: str, value: float) -> CounterMetricFamily:
    return CounterMetricFamily(f"{PREFIX}_{name}", doc, value=float(value))


def metric_families(doc: dict[str, Any]) -> Iterator[Any]:
    """The metrics of one status document."""
    info = InfoMetricFamily(f"{PREFIX}", "The agent's version and the robot it drives.")
    info.add_metric([], {"version": str(doc["version"]), "resource": str(doc["resource"] or "")})
    yield info
    control = doc["control"]
    window = control["window"]
    yield _counter("ticks", "Control loop ticks since the loop process started.", control["ticks"])
    yield _counter("late_ticks", "Ticks that started late.", control["late_ticks"])
    yield _counter("missed_ticks", "Ticks skipped: the loop fell a whole period behind.",
                   control["missed_ticks"])  # fmt: skip
    yield _counter("tick_errors", "Ticks that raised.", control["tick_errors"])
    yield _counter("loop_restarts", "Loop processes started again after dying.",
                   control["restarts"])  # fmt: skip
    yield from _gauge("control_rate_hz", "The control loop's rate.", control["hz"])
    yield from _gauge("loop_running", "1 while the control loop ticks.",
                      _flag(control["running"]))  # fmt: skip
    lateness = GaugeMetricFamily(
        f"{PREFIX}_tick_lateness_seconds",
        f"Tick lateness over the last {window['seconds']:g} s.",
        labels=["quantile"],
    )
    for quantile, key in (("0.5", "lateness_p50_ms"), ("0.99", "lateness_p99_ms"),
                          ("1", "lateness_max_ms")):  # fmt: skip
        if window[key] is not None:
            lateness.add_metric([quantile], window[key] / 1000.0)
    yield lateness
    battery = doc["battery"]
    yield from _gauge("battery_volts", "The robot's battery, filtered.", battery["filtered_v"])
    yield from _gauge("battery_low", "1 when the battery is below its threshold.",
                      _flag(battery["low"]))  # fmt: skip
    yield from _gauge("estop_latched", "1 while an e-stop is latched.",
                      _flag(doc["estop"]["latched"]))  # fmt: skip
    link = doc["link"]
    yield from _gauge("link_up", "1 while the robot's telemetry arrives.",
                      _flag(link["state"] == "up"))  # fmt: skip
    yield from _gauge("link_age_seconds", "Since the robot's last telemetry.", link["age_s"])
    loss = link["loss_pct"]
    yield from _gauge("link_loss_ratio", "Radio frames lost, recently.",
                      None if loss is None else loss / 100.0)  # fmt: skip
    yield from _gauge("link_rssi_dbm", "The radio's signal strength.", link["rssi_dbm"])
    yield from _gauge("run_active", "1 while a run drives the robot.",
                      _flag(doc["current_run"]))  # fmt: skip
    yield from _gauge("clock_synchronized", "1 while the base station's clock is in sync.",
                      _flag(doc["clock_synchronized"]))  # fmt: skip
    host = doc["host"]
    yield from _gauge("disk_free_bytes", "Free space for the run store.", host["disk_free_bytes"])
    yield from _gauge("cpu_temperature_celsius", "The base station's CPU.", host["cpu_temp_c"])
    yield from _gauge("faults", "Faults that keep a run from starting (see /status).",
                      len(doc["faults"]))  # fmt: skip


class _StatusCollector(Collector):
    def __init__(self, doc: dict[str, Any]) -> None:
        self.doc = doc

    def collect(self) -> Iterator[Any]:
        yield from metric_families(self.doc)


@bp.get("/metrics")
def metrics() -> Response:
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_StatusCollector(status_document()))
    return Response(generate_latest(registry), content_type=CONTENT_TYPE_LATEST)
