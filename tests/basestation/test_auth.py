"""Every /api/v1 call needs the bearer token, and a refused call changes nothing."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import pytest
from flask.testing import FlaskClient

from basestation.runtime import AgentRuntime
from tests.basestation.conftest import TOKEN, run_body

CONTROL_BODY = {"user": "mallory", "velocity_mps": 1.0, "direction": "cw", "force": True}

# (method, path, body); "staged" is a run the fixture stages first. Every route the app
# registers is here (test_openapi.py checks that the description covers the same set).
ENDPOINTS: list[tuple[str, str, Any]] = [
    ("GET", "/api/v1/status", None),
    ("GET", "/api/v1/battery", None),
    ("GET", "/api/v1/runs", None),
    ("PUT", "/api/v1/runs/new-run", "run"),
    ("PUT", "/api/v1/runs/staged", "run"),
    ("GET", "/api/v1/runs/staged", None),
    ("DELETE", "/api/v1/runs/staged", None),
    ("GET", "/api/v1/runs/staged/samples", None),
    ("GET", "/api/v1/runs/staged/samples?after=0&limit=10", None),
    ("POST", "/api/v1/control", CONTROL_BODY),
    ("POST", "/api/v1/stop", {"reason": "prank"}),
    ("POST", "/api/v1/stop", None),
    ("POST", "/api/v1/stop/release", None),
    ("GET", "/api/v1/logs/2030-01-01", None),
    ("GET", "/api/v1/logs/../../etc/passwd", None),
    ("GET", "/api/v1/logs/..%2F..%2Fetc%2Fpasswd", None),
    ("GET", "/api/v1/no-such-endpoint", None),
    ("POST", "/api/v1/status", None),
]

BAD_HEADERS: dict[str, dict[str, str]] = {
    "no header": {},
    "wrong token": {"Authorization": "Bearer not-the-token"},
    "token prefix": {"Authorization": f"Bearer {TOKEN[:-1]}"},
    "token with extra": {"Authorization": f"Bearer {TOKEN}x"},
    "basic scheme": {"Authorization": f"Basic {TOKEN}"},
    "bare token": {"Authorization": TOKEN},
    "empty bearer": {"Authorization": "Bearer "},
    "non-ascii": {"Authorization": "Bearer töken"},
}


@pytest.fixture
def staged(client: FlaskClient, auth: dict[str, str], soon: float) -> dict[str, Any]:
    response = client.put("/api/v1/runs/staged", json=run_body(soon), headers=auth)
    assert response.status_code == 201
    return response.json or {}


def _agent_state(runtime: AgentRuntime) -> tuple[Any, ...]:
    """Everything a request could change: runs, e-stop latch, manual control, usage log."""
    return (
        [(r.id, r.state, r.body) for r, _ in runtime.store.list_runs()],
        runtime.manager.estop,
        runtime.manager.manual(time.time()),
        runtime.store.usage_between(0, 4e9),
    )


@pytest.mark.parametrize("headers", BAD_HEADERS.values(), ids=BAD_HEADERS.keys())
@pytest.mark.parametrize(
    ("method", "path", "body"),
    ENDPOINTS,
    ids=[f"{m} {p}{' with body' if b else ''}" for m, p, b in ENDPOINTS],
)
def test_it_refuses_every_api_call_without_the_right_token_and_changes_nothing(
    client: FlaskClient,
    runtime: AgentRuntime,
    staged: dict[str, Any],
    soon: float,
    method: str,
    path: str,
    body: Any,
    headers: dict[str, str],
) -> None:
    before = _agent_state(runtime)
    if body == "run":
        body = run_body(soon + 3600, title="changed")
    response = client.open(path, method=method, json=body, headers=headers)
    assert response.status_code == 401
    assert response.headers["WWW-Authenticate"].startswith("Bearer")
    assert response.is_json
    assert response.json is not None
    assert response.json["error"] == "unauthorized"
    assert response.json["detail"]
    assert _agent_state(runtime) == before


def test_it_serves_healthz_without_a_token(client: FlaskClient) -> None:
    response = client.get("/healthz")
    assert response.status_code == 200
    assert response.json == {"ok": True}


def test_it_accepts_the_right_token_on_every_endpoint(
    client: FlaskClient, auth: dict[str, str], staged: dict[str, Any]
) -> None:
    calls: list[Callable[[], Any]] = [
        lambda: client.get("/api/v1/status", headers=auth),
        lambda: client.get("/api/v1/battery", headers=auth),
        lambda: client.get("/api/v1/runs", headers=auth),
        lambda: client.get("/api/v1/runs/staged", headers=auth),
        lambda: client.get("/api/v1/runs/staged/samples", headers=auth),
        lambda: client.delete("/api/v1/runs/staged", headers=auth),
        lambda: client.post("/api/v1/control", json=CONTROL_BODY, headers=auth),
        lambda: client.post("/api/v1/stop", headers=auth),
        lambda: client.post("/api/v1/stop/release", headers=auth),
        lambda: client.get("/api/v1/logs/2030-01-01", headers=auth),
    ]
    assert [call().status_code for call in calls] == [200] * len(calls)
