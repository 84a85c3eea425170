"""Every /api/v1 call needs the bearer token, and a refused call changes nothing."""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from flask import Flask
from flask.testing import FlaskClient

from basestation.app import create_app
from basestation.config import AgentConfig, ConfigError
from basestation.runtime import AgentRuntime, get_runtime
from tests.basestation.conftest import TOKEN, RecordingRobot, run_body

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


# -- tokens held as digests, one per agent, rotated without a refusal ----------------------

OTHER_AGENTS_TOKEN = "another-agents-token-0123456789abcdef"
NEW_TOKEN = "the-rotated-token-0123456789abcdefghij"


def _digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def _status(app: Flask, token: str) -> int:
    return (
        app.test_client()
        .get("/api/v1/status", headers={"Authorization": f"Bearer {token}"})
        .status_code
    )


@pytest.fixture
def digest_agent(
    agent_config: AgentConfig, robot: RecordingRobot
) -> Iterator[Callable[..., Flask]]:
    apps: list[Flask] = []

    def make(*tokens: str) -> Flask:
        config = replace(agent_config, token="", token_sha256=tuple(_digest(t) for t in tokens))
        app = create_app(config, start_control_loop=False, robot=robot)
        apps.append(app)
        return app

    yield make
    for app in apps:
        get_runtime(app).close()


def test_an_agent_holding_only_a_digest_takes_its_token_and_refuses_another_agents(digest_agent):
    app = digest_agent(TOKEN)
    assert _status(app, TOKEN) == 200
    assert _status(app, OTHER_AGENTS_TOKEN) == 401
    assert TOKEN not in repr(get_runtime(app).config)


def test_a_rotation_accepts_both_tokens_until_the_old_digest_goes(digest_agent):
    during = digest_agent(TOKEN, NEW_TOKEN)
    assert _status(during, TOKEN) == 200
    assert _status(during, NEW_TOKEN) == 200
    after = digest_agent(NEW_TOKEN)
    assert _status(after, NEW_TOKEN) == 200
    assert _status(after, TOKEN) == 401


def test_digests_come_from_the_environment_or_a_file(tmp_path: Path):
    digests = tmp_path / "digests"
    digests.write_text(f"{_digest(TOKEN)}\n{_digest(NEW_TOKEN)}\n")
    config = AgentConfig.from_env({"AGENT_TOKEN_SHA256_FILE": str(digests)})
    assert config.token == ""
    assert config.token_sha256 == (_digest(TOKEN), _digest(NEW_TOKEN))
    inline = AgentConfig.from_env({"AGENT_TOKEN_SHA256": f"{_digest(TOKEN)}, {_digest(NEW_TOKEN)}"})
    assert inline.token_sha256 == config.token_sha256
    with pytest.raises(ConfigError, match="not a SHA-256 digest"):
        AgentConfig.from_env({"AGENT_TOKEN_SHA256": "abc123"})
    with pytest.raises(ConfigError, match="AGENT_TOKEN_SHA256"):
        AgentConfig.from_env({})
