"""The stand-in broker's app, in process: every bad input gets the error envelope."""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import quote

import pytest
from flask import Flask
from flask.testing import FlaskClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bookings.scheduler.standin import (
    ConfigError,
    StandinConfig,
    close_app,
    config_from,
    create_app,
)

NOW_S = 1_900_000_000  # 2030-03-17T17:46:40Z
TOKEN = "in-process-token"


class FixedClock:
    def __init__(self, now_s: float) -> None:
        self.now_s = now_s

    def __call__(self) -> float:
        return self.now_s


@pytest.fixture
def app() -> Iterator[Flask]:
    app = create_app(StandinConfig(test_control=True), clock=FixedClock(NOW_S))
    yield app
    close_app(app)


@pytest.fixture
def client(app: Flask) -> FlaskClient:
    return app.test_client()


def lease_body(**changes: Any) -> dict[str, Any]:
    body: dict[str, Any] = {
        "name": "r-1",
        "valid_from": "2030-03-18T10:00:00Z",
        "valid_until": "2030-03-18T11:00:00Z",
        "account_attributes": {"name": "amazing"},
        "components": [{"name": "node-01"}],
    }
    body.update(changes)
    return body


def assert_envelope(response: Any, code: int, reason_part: str = "") -> None:
    assert response.status_code == code, response.get_data(as_text=True)
    exception = json.loads(response.get_data())["exception"]
    assert exception["code"] == code
    assert reason_part in exception["reason"]


def test_it_answers_in_omf_sfas_envelopes(client: FlaskClient) -> None:
    created = client.post("/resources/leases/", json=lease_body())
    assert created.status_code == 200
    lease = created.get_json()["resource_response"]["resource"]
    assert lease["status"] == "accepted"
    assert lease["account"]["name"] == "amazing"
    assert [c["urn"] for c in lease["components"]] == ["urn:publicid:IDN+amazing+node+node-01"]
    listed = client.get("/resources/leases").get_json()["resource_response"]
    assert listed["about"] == "/resources/leases"
    assert [x["uuid"] for x in listed["resources"]] == [lease["uuid"]]
    deleted = client.delete("/resources/leases", json={"uuid": lease["uuid"]}).get_json()
    assert deleted == {"resource_response": {"response": "OK", "about": "/resources/leases"}}
    node = client.get("/resources/nodes?urn=urn:publicid:IDN%2Bamazing%2Bnode%2Bnode-24")
    assert node.get_json()["resource_response"]["resource"]["name"] == "node-24"


@pytest.mark.parametrize(
    ("body", "code", "reason"),
    [
        (lease_body(components=[]), 400, "components is mandatory"),
        (lease_body(components="node-01"), 400, "components is mandatory"),
        (lease_body(components=["node-01"]), 400, "uuid, name or urn"),
        (lease_body(account_attributes=None), 400, "account is mandatory"),
        (lease_body(account_attributes={"urn": "x"}), 400, "account needs a name"),
        (lease_body(valid_from=None), 400, "must be a time"),
        (lease_body(valid_until="tomorrow"), 400, "Invalid time"),
        (lease_body(valid_until="0001-01-01T00:00:00+05:00"), 400, "out of range"),
        (lease_body(valid_until="2030-03-18T10:00:00Z"), 400, "before valid_until"),
        (lease_body(name=""), 400, "name"),
        ([lease_body()], 400, "JSON object"),
    ],
)
def test_a_bad_lease_is_refused_with_a_reason(
    client: FlaskClient, body: Any, code: int, reason: str
) -> None:
    assert_envelope(client.post("/resources/leases", json=body), code, reason)
    assert client.get("/resources/leases").get_json()["resource_response"]["resources"] == []


def test_bodies_that_are_not_json_and_wrong_paths_or_methods_get_the_envelope(
    client: FlaskClient,
) -> None:
    assert_envelope(client.post("/resources/leases", data=b""), 400, "body is empty")
    assert_envelope(client.post("/resources/leases", data=b"{nope"), 400, "Problems parsing")
    assert_envelope(client.post("/resources/leases", data=b"\xff\xfe\x00"), 400, "parsing")
    assert_envelope(client.put("/resources/leases", data=b"[" * 100_000), 413)
    assert_envelope(client.get("/resources/channels"), 404, "Invalid URL")
    assert_envelope(client.patch("/resources/leases", json={}), 405)
    assert_envelope(client.get("/resources/leases?status=gone"), 400, "Unknown lease status")
    assert_envelope(client.get("/resources/nodes?name=node-99"), 404, "No resources matching")


def test_an_unknown_component_is_left_out_as_omf_sfa_does(client: FlaskClient) -> None:
    body = lease_body(components=[{"name": "node-02"}, {"name": "node-77"}, {"uuid": 5}])
    lease = client.post("/resources/leases", json=body).get_json()["resource_response"]
    assert [c["name"] for c in lease["resource"]["components"]] == ["node-02"]


def test_times_must_sit_on_the_grid(tmp_path: Path) -> None:
    app = create_app(StandinConfig(granularity_s=600), clock=FixedClock(NOW_S))
    client = app.test_client()
    off = lease_body(valid_from="2030-03-18T10:05:00Z")
    assert_envelope(client.post("/resources/leases", json=off), 422, "600s granularity")
    assert client.post("/resources/leases", json=lease_body()).status_code == 200
    close_app(app)


def test_with_a_token_every_resource_call_needs_it() -> None:
    app = create_app(StandinConfig(token=TOKEN), clock=FixedClock(NOW_S))
    client = app.test_client()
    assert_envelope(client.get("/resources/nodes"), 401, "credentials")
    assert_envelope(client.get("/resources/nodes", headers={"Authorization": "Bearer nope"}), 401)
    good = client.get("/resources/nodes", headers={"Authorization": f"Bearer {TOKEN}"})
    assert len(good.get_json()["resource_response"]["resources"]) == 24
    close_app(app)


def test_test_control_is_served_only_when_switched_on() -> None:
    app = create_app(StandinConfig(), clock=FixedClock(NOW_S))
    client = app.test_client()
    for path in ("/_standin/reset", "/_standin/clock", "/_standin/faults", "/_standin/leases"):
        assert_envelope(client.post(path, json={}), 404)
    close_app(app)


def test_test_control_refuses_bad_values(client: FlaskClient) -> None:
    assert_envelope(client.post("/_standin/faults", json={"delay_s": -1}), 400)
    assert_envelope(client.post("/_standin/faults", json={"delay_s": 1e9}), 400)
    assert_envelope(client.post("/_standin/faults", json={"unavailable": "yes"}), 400)
    assert_envelope(client.post("/_standin/faults", json={"answer_delay_s": -2}), 400)
    assert_envelope(client.post("/_standin/clock", json={"offset_s": True}), 400)
    assert_envelope(client.post("/_standin/clock", json={}), 400)
    assert_envelope(client.post("/_standin/leases", json=lease_body(status="active")), 400)
    assert client.get("/_standin/faults").get_json() == {
        "delay_s": 0.0,
        "unavailable": False,
        "answer_delay_s": 0.0,
    }


def test_a_lease_file_survives_a_restart(tmp_path: Path) -> None:
    config = StandinConfig(db_path=str(tmp_path / "leases.sqlite3"))
    first = create_app(config, clock=FixedClock(NOW_S))
    made = first.test_client().post("/resources/leases", json=lease_body()).get_json()
    close_app(first)
    second = create_app(config, clock=FixedClock(NOW_S + 86400))
    listed = second.test_client().get("/resources/leases?status=past").get_json()
    (lease,) = listed["resource_response"]["resources"]
    assert lease["uuid"] == made["resource_response"]["resource"]["uuid"]
    assert lease["status"] == "past"
    close_app(second)


def test_flags_override_the_environment(tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token_file.write_text("from-file\n")
    env = {
        "SCHEDULER_STANDIN_CONFLICT_AS": "409",
        "SCHEDULER_STANDIN_GRANULARITY_S": "60",
        "SCHEDULER_STANDIN_EMPTY_AS_404": "on",
        "SCHEDULER_STANDIN_NODES": "a-1, a-2",
        "SCHEDULER_STANDIN_TOKEN_FILE": str(token_file),
    }
    nothing = argparse.Namespace(
        conflict_as=None,
        granularity_s=None,
        empty_as_404=None,
        test_control=None,
        nodes=None,
        db=None,
        token=None,
        token_file=None,
    )
    config = config_from(nothing, env)
    assert (config.conflict_as, config.granularity_s, config.empty_as_404) == ("409", 60, True)
    assert config.nodes == ("a-1", "a-2")
    assert config.token == "from-file"
    flags = argparse.Namespace(**{**vars(nothing), "conflict_as": "zombie", "empty_as_404": False})
    overridden = config_from(flags, env)
    assert (overridden.conflict_as, overridden.empty_as_404) == ("zombie", False)


@pytest.mark.parametrize(
    "env",
    [
        {"SCHEDULER_STANDIN_CONFLICT_AS": "418"},
        {"SCHEDULER_STANDIN_GRANULARITY_S": "ten"},
        {"SCHEDULER_STANDIN_GRANULARITY_S": "0"},
        {"SCHEDULER_STANDIN_EMPTY_AS_404": "perhaps"},
        {"SCHEDULER_STANDIN_NODES": "node 1"},
        {"SCHEDULER_STANDIN_NODES": "n-1,n-1"},
        {"SCHEDULER_STANDIN_TOKEN": "a", "SCHEDULER_STANDIN_TOKEN_FILE": "/x"},
        {"SCHEDULER_STANDIN_TOKEN_FILE": "/nonexistent/token"},
    ],
)
def test_a_bad_switch_is_a_configuration_error(env: dict[str, str]) -> None:
    with pytest.raises(ConfigError):
        StandinConfig.from_env(env)


# -- whatever a client sends, the answer is an envelope, never a 500 ----------------------

json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats(allow_nan=False)
    | st.text(max_size=30)
    | st.sampled_from(
        ["2030-03-18T10:00:00Z", "2030-03-18T11:00:00+01:00", "node-01", "amazing", ""]
    ),
    lambda children: (
        st.lists(children, max_size=4)
        | st.dictionaries(
            st.sampled_from(
                [
                    "uuid",
                    "name",
                    "urn",
                    "valid_from",
                    "valid_until",
                    "account",
                    "account_attributes",
                    "components",
                    "components_attributes",
                    "status",
                ]
            )
            | st.text(max_size=8),
            children,
            max_size=7,
        )
    ),
    max_leaves=25,
)


def assert_well_formed(response: Any) -> None:
    assert response.status_code < 500, response.get_data(as_text=True)
    payload = json.loads(response.get_data())
    if response.status_code >= 400:
        assert set(payload) == {"exception"}
        assert payload["exception"]["code"] == response.status_code
        assert isinstance(payload["exception"]["reason"], str)
    else:
        assert "resource_response" in payload


@settings(
    max_examples=300,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(method=st.sampled_from(["POST", "PUT", "DELETE"]), body=json_values)
def test_any_json_body_gets_an_answer_or_the_envelope(
    client: FlaskClient, method: str, body: object
) -> None:
    response = client.open("/resources/leases", method=method, data=json.dumps(body))
    assert_well_formed(response)


@settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    method=st.sampled_from(["POST", "PUT", "DELETE", "GET"]),
    path=st.sampled_from(["/resources/leases", "/resources/nodes", "/_standin/clock"]),
    body=st.binary(max_size=300),
    query=st.text(max_size=40)
    | st.sampled_from(["status=", "status=past,,x", "uuid=1&name=2", "name=node-01&urn="]),
)
def test_any_bytes_and_query_get_an_answer_or_the_envelope(
    client: FlaskClient, method: str, path: str, body: bytes, query: str
) -> None:
    url = f"{path}?{quote(query, safe='=&,;')}"
    response = client.open(url, method=method, data=body)
    assert response.status_code < 500, response.get_data(as_text=True)
    json.loads(response.get_data())
