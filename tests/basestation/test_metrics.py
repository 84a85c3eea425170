"""``GET /api/v1/metrics``: the base station's state in Prometheus's format, equal to /status."""

from __future__ import annotations

from collections.abc import Callable

from flask.testing import FlaskClient
from prometheus_client.parser import text_string_to_metric_families

from basestation.runtime import AgentRuntime


def _samples(
    client: FlaskClient, auth: dict[str, str]
) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    response = client.get("/api/v1/metrics", headers=auth)
    assert response.status_code == 200
    assert response.content_type.startswith("text/plain")
    found = {}
    for family in text_string_to_metric_families(response.get_data(as_text=True)):
        for sample in family.samples:
            found[(sample.name, tuple(sorted(sample.labels.items())))] = sample.value
    return found


def test_the_metrics_say_what_the_status_says(
    client: FlaskClient,
    auth: dict[str, str],
    runtime: AgentRuntime,
    drive: Callable[[float, float], float],
) -> None:
    drive(1000.0, 1005.0)
    status = client.get("/api/v1/status", headers=auth).json
    assert status is not None
    metrics = _samples(client, auth)
    control = status["control"]
    assert metrics[("amazing_agent_ticks_total", ())] == control["ticks"]
    assert metrics[("amazing_agent_missed_ticks_total", ())] == control["missed_ticks"]
    assert metrics[("amazing_agent_control_rate_hz", ())] == control["hz"]
    assert metrics[("amazing_agent_battery_volts", ())] == status["battery"]["filtered_v"]
    assert metrics[("amazing_agent_estop_latched", ())] == 0.0
    assert metrics[("amazing_agent_faults", ())] == len(status["faults"])
    info = (
        "amazing_agent_info",
        (("resource", status["resource"] or ""), ("version", status["version"])),
    )
    assert metrics[info] == 1.0


def test_a_latched_estop_shows_in_the_metrics(
    client: FlaskClient, auth: dict[str, str], drive: Callable[[float, float], float]
) -> None:
    drive(1000.0, 1001.0)
    stopped = client.post("/api/v1/stop", json={"reason": "someone on the roof"}, headers=auth)
    assert stopped.status_code == 200, stopped.json
    assert _samples(client, auth)[("amazing_agent_estop_latched", ())] == 1.0


def test_the_metrics_need_the_token(client: FlaskClient) -> None:
    assert client.get("/api/v1/metrics").status_code == 401
