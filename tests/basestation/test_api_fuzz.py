"""Property-based fuzzing of the whole agent API: whatever arrives, no 5xx, always JSON.

Paths are built from the real routes with fuzzed segments (path traversal, percent-encoding,
odd ids and dates), with any method, query string, headers and body. test_put_fuzz.py goes
deeper into run bodies.
"""

from __future__ import annotations

import json
from typing import Any
from urllib.parse import quote

from flask.testing import FlaskClient
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from basestation.app import MAX_BODY_BYTES
from basestation.runtime import AgentRuntime
from tests.basestation.conftest import TOKEN

AUTH = {"Authorization": f"Bearer {TOKEN}"}
FUZZ = settings(
    max_examples=300,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

TRAVERSALS = [
    "..",
    "../..",
    "../../etc/passwd",
    "..%2F..%2Fetc%2Fpasswd",
    "%2e%2e%2f%2e%2e%2fetc%2fpasswd",
    "%252e%252e%252f",
    "..\\..\\windows\\win.ini",
    "%c0%ae%c0%ae%2f",
    "....//....//etc/passwd",
    "/etc/passwd",
    "%00",
    "2030-01-01%00.txt",
    "2030-01-01/../../../etc/passwd",
    ".",
    "~root",
]
segments = (
    st.sampled_from(TRAVERSALS)
    | st.sampled_from(["r1", "2030-01-01", "2019-02-30", "9999-12-31", "0001-01-01", ""])
    | st.text(alphabet="abcXYZ019_-.~%/\\ :&=", max_size=40)
    | st.text(max_size=20).map(lambda text: quote(text, safe=""))
)
templates = st.sampled_from(
    [
        "/healthz",
        "/api/v1/status",
        "/api/v1/battery",
        "/api/v1/runs",
        "/api/v1/runs/{}",
        "/api/v1/runs/{}/samples",
        "/api/v1/control",
        "/api/v1/stop",
        "/api/v1/stop/release",
        "/api/v1/logs/{}",
        "/api/v1/{}",
        "/{}",
    ]
)
methods = st.sampled_from(["GET", "POST", "PUT", "DELETE", "PATCH", "HEAD", "OPTIONS"])
json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=20)
    | st.sampled_from(["cw", "ccw", "admin", "\ud800", 10**400]),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=12), children, max_size=5)
    ),
    max_leaves=20,
)
control_bodies = st.fixed_dictionaries(
    {},
    optional={
        "user": st.text(max_size=160) | json_values,
        "velocity_mps": st.floats(-1, 3) | json_values,
        "direction": st.sampled_from(["cw", "ccw"]) | json_values,
        "ttl_s": st.floats(-1, 12) | json_values,
        "force": st.booleans() | json_values,
        "reason": st.text(max_size=210) | json_values,
    },
)
bodies = (
    st.none()
    | json_values.map(lambda value: json.dumps(value).encode())
    | control_bodies.map(lambda value: json.dumps(value).encode())
    | st.binary(max_size=200)
)
queries = st.dictionaries(
    st.sampled_from(["after", "limit", "state", "x"]),
    st.sampled_from(["0", "1", "-1", "5001", "1e3", "running", "", "%00", "9" * 30]),
    max_size=3,
)
auth_headers = st.sampled_from([AUTH, AUTH, AUTH, {}, {"Authorization": "Bearer wrong"}])
content_types = st.sampled_from(
    ["application/json", "application/json; charset=utf-8", "text/plain", None]
)
accepts = st.sampled_from(["application/json", "text/csv", "*/*", "text/html", None])


def _assert_json_client_answer(response: Any, method: str) -> None:
    event(f"status {response.status_code}")
    assert response.status_code < 500, response.get_data(as_text=True)
    if method != "HEAD":
        assert response.is_json or response.mimetype == "text/csv"


@FUZZ
@given(
    method=methods,
    template=templates,
    segment=segments,
    query=queries,
    body=bodies,
    headers=auth_headers,
    content_type=content_types,
    accept=accepts,
)
def test_no_request_makes_the_agent_fail(
    client: FlaskClient,
    method: str,
    template: str,
    segment: str,
    query: dict[str, str],
    body: bytes | None,
    headers: dict[str, str],
    content_type: str | None,
    accept: str | None,
) -> None:
    path = template.format(segment)
    all_headers = dict(headers)
    if accept is not None:
        all_headers["Accept"] = accept
    response = client.open(
        path,
        method=method,
        query_string=query,
        data=body,
        content_type=content_type,
        headers=all_headers,
    )
    _assert_json_client_answer(response, method)
    if headers is not AUTH and path.startswith("/api/v1"):
        assert response.status_code == 401


@FUZZ
@given(segment=st.sampled_from(TRAVERSALS) | segments)
def test_path_traversal_in_a_log_date_never_reads_a_file(client: FlaskClient, segment: str) -> None:
    response = client.get(f"/api/v1/logs/{segment}", headers=AUTH)
    _assert_json_client_answer(response, "GET")
    text = response.get_data(as_text=True)
    assert "root:" not in text
    assert "[fonts]" not in text
    if response.status_code == 200:
        # Only a real date answers, and then with that day's log.
        assert response.json is not None
        assert response.json["date"] == segment


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    method=st.sampled_from(["GET", "POST", "PUT", "DELETE"]),
    path=st.sampled_from(
        [
            "/api/v1/status",
            "/api/v1/battery",
            "/api/v1/control",
            "/api/v1/stop",
            "/api/v1/stop/release",
            "/api/v1/runs/r1",
            "/api/v1/logs/2030-01-01",
        ]
    ),
    extra=st.integers(min_value=1, max_value=4096),
)
def test_oversized_bodies_are_refused_on_every_endpoint_and_change_nothing(
    client: FlaskClient, runtime: AgentRuntime, method: str, path: str, extra: int
) -> None:
    body = b'{"user": "x", "reason": "' + b"a" * (MAX_BODY_BYTES + extra) + b'"}'
    response = client.open(
        path, method=method, data=body, content_type="application/json", headers=AUTH
    )
    if (method, path) == ("POST", "/api/v1/stop"):
        # A stop is never refused for its body (tests/security/test_stop.py): it latches.
        assert response.status_code == 200, response.json
        assert runtime.manager.estop is not None
        released = client.post("/api/v1/stop/release", json={"user": "x"}, headers=AUTH)
        assert released.status_code == 200, released.json
        assert runtime.store.list_runs() == []
        return
    assert response.status_code == 413
    assert response.json is not None
    assert response.json["error"] == "request_entity_too_large"
    assert runtime.manager.estop is None
    assert runtime.store.list_runs() == []
