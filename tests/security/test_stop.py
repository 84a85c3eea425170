"""The stop's door (DESIGN §8): refused only for authentication, at the portal and at the
agent, whatever its body; served while the agent's request threads are all busy; and the
agent's read-only token refused every control endpoint."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import requests
from flask import Flask
from flask.testing import FlaskClient

from basestation.app import create_app
from basestation.config import AgentConfig
from basestation.manual import MAX_REASON_CHARS
from basestation.runtime import AgentRuntime, get_runtime
from basestation.serve import make_server
from core.audit.models import AuditEvent
from tests.basestation.conftest import TOKEN, run_body
from tests.factories import UserFactory

READ_TOKEN = "read-only-token-0123456789abcdef"
LONG = "why " * 75  # 300 characters
HUGE = "x" * 10_000
CONTROL = "roof\x00door\x07open\r\n\x1b[31m\tclosed"
UNICODE = "pessoa no telhado 🚨 — 屋上に人 \u202e\ufeff"

# (name, what is sent, the reason the portal's audit keeps)
HOSTILE_JSON: list[tuple[str, Any, str]] = [
    ("300 characters", {"reason": LONG}, LONG),
    ("10 000 characters", {"reason": HUGE}, HUGE),
    ("control characters", {"reason": CONTROL}, CONTROL.replace("\x00", "\ufffd")),
    ("unicode", {"reason": UNICODE}, UNICODE),
    ("extra field", {"reason": "rail blocked", "speed": 9, "user": "mallory"}, "rail blocked"),
    ("no reason", {}, ""),
    ("reason not a string", {"reason": ["a", 1]}, '["a", 1]'),
    ("a JSON array", [1, 2], ""),
]


def _latched(runtime: AgentRuntime) -> bool:
    return runtime.manager.estop is not None


# -- at the portal -------------------------------------------------------------------------------


@pytest.fixture
def robot(agent, mobile):
    mobile.agent_url = agent.url
    mobile.save()
    return mobile


STOP_URL = "/api/v1/resources/mobile-1/robot/stop/"


@pytest.mark.django_db
@pytest.mark.parametrize(
    ("body", "kept"), [(b, k) for _, b, k in HOSTILE_JSON], ids=[n for n, _, _ in HOSTILE_JSON]
)
def test_the_portal_stops_the_robot_whatever_the_reason_and_audits_it_whole(
    robot,
    agent,
    admin_user,
    client_for,
    body,
    kept,
):
    response = client_for(admin_user).post(STOP_URL, body, format="json")
    assert response.status_code == 200, response.content
    assert _latched(agent.runtime)
    event = AuditEvent.objects.get(action="robot.stop")
    if isinstance(body, dict) or kept:
        assert event.reason == kept
    assert "failed" not in event.data
    assert "refused" not in event.data


@pytest.mark.django_db
@pytest.mark.parametrize(
    ("content", "content_type"),
    [
        (b"STOP NOW \xff\xfe", "text/plain"),
        (b'{"reason": "cut', "application/json"),
        (b"reason=person+on+the+roof", "application/x-www-form-urlencoded"),
    ],
    ids=["not text", "broken JSON", "a form"],
)
def test_the_portal_stops_the_robot_for_a_body_that_is_not_json(
    robot,
    agent,
    admin_user,
    client_for,
    content,
    content_type,
):
    response = client_for(admin_user).generic("POST", STOP_URL, content, content_type)
    assert response.status_code == 200, response.content
    assert _latched(agent.runtime)
    event = AuditEvent.objects.get(action="robot.stop")
    assert event.reason == content.decode("utf-8", "replace")


@pytest.mark.django_db
def test_the_agent_keeps_the_first_characters_and_says_so(
    robot,
    agent,
    admin_user,
    client_for,
):
    response = client_for(admin_user).post(STOP_URL, {"reason": LONG}, format="json")
    assert response.json()["truncated"] == ["reason"]
    assert agent.runtime.manager.estop.reason.startswith(LONG[:MAX_REASON_CHARS].rstrip())


@pytest.mark.django_db
def test_the_portal_stops_the_robot_for_a_reason_postgresql_cannot_store(
    robot,
    agent,
    admin_user,
    client_for,
):
    body = b'{"reason": "a\\ud800b\\u0000c"}'  # a lone surrogate and NUL, as JSON escapes
    response = client_for(admin_user).generic("POST", STOP_URL, body, "application/json")
    assert response.status_code == 200, response.content
    assert _latched(agent.runtime)
    assert AuditEvent.objects.get(action="robot.stop").reason == "a\ufffdb\ufffdc"


@pytest.mark.django_db
@pytest.mark.parametrize("who", ["anonymous", "experimenter"])
def test_the_portal_refuses_a_stop_only_to_who_may_not_stop(
    robot,
    agent,
    client_for,
    who,
):
    user = {
        "anonymous": None,
        "experimenter": UserFactory(username="bob"),
    }[who]
    response = client_for(user).post(STOP_URL, {"reason": "x"}, format="json")
    assert response.status_code in (401, 403)
    assert not _latched(agent.runtime)


# -- at the agent --------------------------------------------------------------------------------


@pytest.fixture
def agent_app(tmp_path) -> Iterator[Flask]:
    config = AgentConfig(
        token=TOKEN, read_token=READ_TOKEN, data_dir=tmp_path / "agent", robot="simple"
    )
    app = create_app(config, start_control_loop=False)
    yield app
    get_runtime(app).close()


@pytest.fixture
def agent_client(agent_app: Flask) -> FlaskClient:
    return agent_app.test_client()


def _bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


@pytest.mark.parametrize(
    "body", [b for _, b, _ in HOSTILE_JSON], ids=[n for n, _, _ in HOSTILE_JSON]
)
def test_the_agent_latches_whatever_the_json(agent_app, agent_client, body):
    response = agent_client.post("/api/v1/stop", json=body, headers=_bearer(TOKEN))
    assert response.status_code == 200, response.json
    latch = get_runtime(agent_app).manager.estop
    assert latch is not None
    assert len(latch.reason) <= MAX_REASON_CHARS + len(" (by mallory)")


@pytest.mark.parametrize(
    ("data", "content_type"),
    [
        (b"\xff\xfe\x00garbage", "application/octet-stream"),
        (b"{not json", "application/json"),
        (b"stop", None),
        (b"x" * (200 * 1024), "application/json"),  # over the 64 KiB every other body may be
    ],
    ids=["bytes", "broken JSON", "no type", "200 KiB"],
)
def test_the_agent_latches_for_a_body_that_is_not_json(agent_app, agent_client, data, content_type):
    response = agent_client.post(
        "/api/v1/stop", data=data, content_type=content_type, headers=_bearer(TOKEN)
    )
    assert response.status_code == 200, response.json
    assert response.json["ignored"] == ["body"]
    assert get_runtime(agent_app).manager.estop is not None


def test_the_agent_cuts_a_long_reason_to_what_it_stores_and_says_so(agent_app, agent_client):
    response = agent_client.post(
        "/api/v1/stop", json={"reason": HUGE, "why": 1}, headers=_bearer(TOKEN)
    )
    assert response.json["truncated"] == ["reason"]
    assert response.json["ignored"] == ["why"]
    latch = get_runtime(agent_app).manager.estop
    assert latch is not None
    assert latch.reason == HUGE[:MAX_REASON_CHARS]
    stored = get_runtime(agent_app).store.get_estop()
    assert stored is not None
    assert stored[1] == HUGE[:MAX_REASON_CHARS]


@pytest.mark.parametrize(
    "headers",
    [{}, _bearer("wrong-token-0123456789"), {"Authorization": TOKEN}, _bearer("")],
    ids=["no token", "wrong token", "no scheme", "empty"],
)
def test_the_agent_refuses_a_stop_without_a_valid_token(agent_app, agent_client, headers):
    response = agent_client.post("/api/v1/stop", json={"reason": "x"}, headers=headers)
    assert response.status_code == 401
    assert get_runtime(agent_app).manager.estop is None


def test_the_read_only_token_may_stop_but_never_release(agent_app, agent_client):
    runtime = get_runtime(agent_app)
    assert agent_client.post("/api/v1/stop", headers=_bearer(READ_TOKEN)).status_code == 200
    assert runtime.manager.estop is not None
    refused = agent_client.post("/api/v1/stop/release", headers=_bearer(READ_TOKEN))
    assert refused.status_code == 403
    assert runtime.manager.estop is not None


def _control_routes(app: Flask) -> list[tuple[str, str]]:
    """Every route and method of /api/v1 but reading and the stop, from the URL map: a new
    control route is in this list the day it is added."""
    routes = []
    for rule in app.url_map.iter_rules():
        if not rule.rule.startswith("/api/v1"):
            continue
        path = rule.rule.replace("<run_id>", "run-1").replace("<day>", "2030-01-01")
        path = path.replace("<string:run_id>", "run-1").replace("<string:day>", "2030-01-01")
        for method in sorted((rule.methods or set()) - {"GET", "HEAD", "OPTIONS"}):
            if (method, rule.rule) != ("POST", "/api/v1/stop"):
                routes.append((method, path))
    return routes


def test_the_url_map_has_control_routes_to_attack(agent_app):
    routes = set(_control_routes(agent_app))
    assert {("POST", "/api/v1/control"), ("POST", "/api/v1/stop/release")} <= routes
    assert {("PUT", "/api/v1/runs/run-1"), ("DELETE", "/api/v1/runs/run-1")} <= routes


def test_the_read_only_token_is_refused_every_control_route_and_changes_nothing(
    agent_app, agent_client
):
    runtime = get_runtime(agent_app)
    soon = round(time.time()) + 60.0
    assert (
        agent_client.put("/api/v1/runs/run-1", json=run_body(soon), headers=_bearer(TOKEN))
    ).status_code == 201
    agent_client.post("/api/v1/stop", headers=_bearer(TOKEN))
    bodies = {"/api/v1/runs/run-1": run_body(soon + 3600), "/api/v1/control": {}}
    for method, path in _control_routes(agent_app):
        response = agent_client.open(
            path, method=method, json=bodies.get(path, {"user": "x"}), headers=_bearer(READ_TOKEN)
        )
        assert response.status_code == 403, (method, path, response.json)
    run = runtime.store.get_run("run-1")
    assert run is not None
    assert run.state == "staged"
    assert runtime.manager.estop is not None


@pytest.mark.parametrize(
    "path", ["/api/v1/status", "/api/v1/battery", "/api/v1/runs", "/api/v1/metrics"]
)
def test_the_read_only_token_reads(agent_client, path):
    assert agent_client.get(path, headers=_bearer(READ_TOKEN)).status_code == 200


# -- ahead of the queue --------------------------------------------------------------------------


def _serving(server: Any) -> threading.Thread:
    """``server.run()`` in a thread of its own. Closing the server under its loop at the end
    of a test makes the loop meet a closed descriptor (OSError): that is the test's own close,
    and ends the thread quietly instead of failing whichever test runs next."""

    def run() -> None:
        with contextlib.suppress(OSError, ValueError):
            server.run()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def _close(server: Any, runtime: Any, holders: list[threading.Thread]) -> None:
    """The server, then the store (which wakes the long-polls: they answer and end), then the
    test's own threads: nothing of a test runs on into the next."""
    server.close()
    runtime.close()
    for holder in holders:
        holder.join(DEADLINE_S)


HOLD_S = 30  # the slow requests' long-poll: far longer than the deadline below
DEADLINE_S = 10.0  # bounds a hang only


def test_a_stop_is_answered_while_every_request_thread_is_busy(agent_app):
    """Two threads, four long-polls that hold them (and queue behind them): the stop has
    threads of its own."""
    runtime = get_runtime(agent_app)
    client = agent_app.test_client()
    soon = round(time.time()) + 60.0
    client.put("/api/v1/runs/run-1", json=run_body(soon), headers=_bearer(TOKEN))
    server = make_server(agent_app, host="127.0.0.1", port=0, threads=2)
    _serving(server)
    url = f"http://127.0.0.1:{server.effective_port}"  # type: ignore[attr-defined]
    dispatcher = server.task_dispatcher
    slow = f"{url}/api/v1/runs/run-1/samples?wait_s={HOLD_S}"

    def hold() -> None:
        with contextlib.suppress(requests.RequestException):
            requests.get(slow, headers=_bearer(TOKEN), timeout=HOLD_S + 5)

    holders = [threading.Thread(target=hold, daemon=True) for _ in range(4)]
    try:
        for holder in holders:
            holder.start()
        # Wait on the thing: both threads serving a slow request, two more queued.
        deadline = time.monotonic() + DEADLINE_S
        while not (dispatcher.active_count == 2 and len(dispatcher.queue) == 2):
            assert time.monotonic() < deadline, "the slow requests never held the threads"
            time.sleep(0.01)
        response = requests.post(
            f"{url}/api/v1/stop",
            json={"reason": "person on the roof"},
            headers=_bearer(TOKEN),
            timeout=DEADLINE_S,
        )
        assert response.status_code == 200
        assert runtime.manager.estop is not None
        assert dispatcher.active_count == 2  # the slow requests still hold every thread
    finally:
        _close(server, runtime, holders)


def test_a_long_poll_gives_its_cpu_slot_back_while_it_waits(agent_app):
    """One CPU slot, a long-poll waiting for samples: a status read still runs at once (the
    wait holds a thread, not the slot)."""
    runtime = get_runtime(agent_app)
    client = agent_app.test_client()
    soon = round(time.time()) + 60.0
    client.put("/api/v1/runs/run-1", json=run_body(soon), headers=_bearer(TOKEN))
    server = make_server(agent_app, host="127.0.0.1", port=0, threads=4, cpu_slots=1)
    _serving(server)
    url = f"http://127.0.0.1:{server.effective_port}"  # type: ignore[attr-defined]
    dispatcher = server.task_dispatcher

    def hold() -> None:
        with contextlib.suppress(requests.RequestException):
            requests.get(
                f"{url}/api/v1/runs/run-1/samples?wait_s={HOLD_S}",
                headers=_bearer(TOKEN),
                timeout=HOLD_S + 5,
            )

    holder = threading.Thread(target=hold, daemon=True)
    try:
        holder.start()
        deadline = time.monotonic() + DEADLINE_S
        while dispatcher.active_count != 1:
            assert time.monotonic() < deadline, "the long-poll never started"
            time.sleep(0.01)
        # Without the slot given back, this waits for the long-poll's 30 s and times out.
        status = requests.get(f"{url}/api/v1/status", headers=_bearer(TOKEN), timeout=DEADLINE_S)
        assert status.status_code == 200
        assert dispatcher.active_count >= 1  # the long-poll is still waiting
    finally:
        _close(server, runtime, [holder])
