"""Every /api/v1 call needs the bearer token, and a refused call changes nothing."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
from flask.testing import FlaskClient

from basestation.runtime import AgentRuntime
from tests.basestation.conftest import TOKEN, run_body

# (method, path, body); "staged" is a run the fixture stages first.
ENDPOINTS: list[tuple[str, str, bool]] = [
    ("GET", "/api/v1/status", False),
    ("GET", "/api/v1/runs", False),
    ("PUT", "/api/v1/runs/new-run", True),
    ("PUT", "/api/v1/runs/staged", True),
    ("GET", "/api/v1/runs/staged", False),
    ("DELETE", "/api/v1/runs/staged", False),
    ("GET", "/api/v1/runs/staged/samples", False),
    ("GET", "/api/v1/runs/staged/samples?after=0&limit=10", False),
    ("GET", "/api/v1/no-such-endpoint", False),
    ("POST", "/api/v1/status", False),
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


def _runs(runtime: AgentRuntime) -> list[tuple[str, str, str]]:
    return [(r.id, r.state, r.body) for r, _ in runtime.store.list_runs()]


@pytest.mark.parametrize("headers", BAD_HEADERS.values(), ids=BAD_HEADERS.keys())
@pytest.mark.parametrize(
    ("method", "path", "with_body"), ENDPOINTS, ids=[f"{m} {p}" for m, p, _ in ENDPOINTS]
)
def test_it_refuses_every_api_call_without_the_right_token_and_changes_nothing(
    client: FlaskClient,
    runtime: AgentRuntime,
    staged: dict[str, Any],
    soon: float,
    method: str,
    path: str,
    with_body: bool,
    headers: dict[str, str],
) -> None:
    before = _runs(runtime)
    body = run_body(soon + 3600, title="changed") if with_body else None
    response = client.open(path, method=method, json=body, headers=headers)
    assert response.status_code == 401
    assert response.headers["WWW-Authenticate"].startswith("Bearer")
    assert response.is_json
    assert response.json is not None
    assert response.json["error"] == "unauthorized"
    assert response.json["detail"]
    assert _runs(runtime) == before


def test_it_serves_healthz_without_a_token(client: FlaskClient) -> None:
    response = client.get("/healthz")
    assert response.status_code == 200
    assert response.json == {"ok": True}


def test_it_accepts_the_right_token_on_every_endpoint(
    client: FlaskClient, auth: dict[str, str], staged: dict[str, Any]
) -> None:
    calls: list[Callable[[], Any]] = [
        lambda: client.get("/api/v1/status", headers=auth),
        lambda: client.get("/api/v1/runs", headers=auth),
        lambda: client.get("/api/v1/runs/staged", headers=auth),
        lambda: client.get("/api/v1/runs/staged/samples", headers=auth),
        lambda: client.delete("/api/v1/runs/staged", headers=auth),
    ]
    assert [call().status_code for call in calls] == [200] * len(calls)
