"""Whatever a client PUTs, the agent answers with a client error or success, never a 5xx."""

from __future__ import annotations

import json
import time
from typing import Any

from flask.testing import FlaskClient
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from tests.basestation.conftest import TOKEN, iso, run_body

AUTH = {"Authorization": f"Bearer {TOKEN}"}
FUZZ = settings(
    max_examples=150,
    deadline=None,
    # The app fixture is shared across examples on purpose: runs staged by earlier
    # examples make later ones meet the 409 paths too.
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)

json_scalars = (
    st.none()
    | st.booleans()
    | st.integers()
    | st.just(10**400)
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=30)
    | st.sampled_from(["cw", "ccw", "2030-01-01T00:00:00Z", "2030-01-01T00:00:00", "\ud800"])
)
json_values = st.recursive(
    json_scalars,
    lambda children: (
        st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=15), children, max_size=5)
    ),
    max_leaves=25,
)

_now = time.time()
time_strings = st.floats(min_value=_now - 86_400, max_value=_now + 86_400 * 30).map(iso)
segments = st.lists(
    st.fixed_dictionaries(
        {
            "velocity_mps": st.floats(-1, 3) | json_values,
            "direction": st.sampled_from(["cw", "ccw"]) | json_values,
            "duration_s": st.floats(-1, 100) | json_values,
        },
        optional={"extra": json_values},
    ),
    max_size=6,
)
body_shaped = st.fixed_dictionaries(
    {},
    optional={
        "owner": st.text(max_size=20) | json_values,
        "title": st.text(max_size=20) | json_values,
        "start_at": time_strings | json_values,
        "end_at": time_strings | json_values,
        "segments": segments | json_values,
        "limits": st.fixed_dictionaries(
            {
                "max_velocity_mps": st.floats(-1, 5) | json_values,
                "max_accel_mps2": st.floats(-1, 5) | json_values,
            }
        )
        | json_values,
        "unexpected": json_values,
    },
)


@st.composite
def nearly_valid_bodies(draw: st.DrawFn) -> dict[str, Any]:
    """A valid body with zero to two fields (top level or in a segment) replaced."""
    start_s = draw(st.floats(min_value=_now + 60, max_value=_now + 600)) // 1
    body = run_body(start_s, window_s=draw(st.sampled_from([6.0, 10.0, 30.0])))
    for _ in range(draw(st.integers(0, 2))):
        value = draw(json_values | st.floats(-2, 200) | time_strings)
        where = draw(st.sampled_from(["top", "segment", "limits"]))
        if where == "top":
            body[draw(st.sampled_from([*body, "extra"]))] = value
        elif where == "segment" and isinstance(body.get("segments"), list) and body["segments"]:
            # (An earlier replacement may have left segments that are not objects.)
            segment = body["segments"][draw(st.integers(0, len(body["segments"]) - 1))]
            if isinstance(segment, dict):
                field = draw(st.sampled_from(["velocity_mps", "direction", "duration_s", "x"]))
                segment[field] = value
        elif isinstance(body.get("limits"), dict):
            body["limits"][draw(st.sampled_from(["max_velocity_mps", "max_accel_mps2"]))] = value
    return body


run_ids = st.text(alphabet="abcXYZ019_-.~ %", min_size=1, max_size=70)


def _assert_client_answer(response: Any) -> None:
    event(f"status {response.status_code}")
    assert response.status_code < 500, response.get_data(as_text=True)
    assert response.is_json
    if response.status_code >= 400:
        assert isinstance(response.json["error"], str)


@FUZZ
@given(body=json_values)
def test_put_never_fails_on_arbitrary_json(client: FlaskClient, body: Any) -> None:
    response = client.put(
        "/api/v1/runs/fuzz", data=json.dumps(body), content_type="application/json", headers=AUTH
    )
    _assert_client_answer(response)
    assert response.status_code in (200, 201, 409, 422)


@FUZZ
@given(body=body_shaped, run_id=st.sampled_from(["a", "b", "c"]) | run_ids)
def test_put_never_fails_on_run_shaped_bodies(
    client: FlaskClient, body: dict[str, Any], run_id: str
) -> None:
    response = client.put(
        f"/api/v1/runs/{run_id}",
        data=json.dumps(body),
        content_type="application/json",
        headers=AUTH,
    )
    _assert_client_answer(response)


@FUZZ
@given(body=nearly_valid_bodies(), run_id=st.sampled_from(["a", "b", "c", "d"]))
def test_put_never_fails_on_nearly_valid_bodies(
    client: FlaskClient, body: dict[str, Any], run_id: str
) -> None:
    response = client.put(
        f"/api/v1/runs/{run_id}",
        data=json.dumps(body),
        content_type="application/json",
        headers=AUTH,
    )
    _assert_client_answer(response)
    assert response.status_code in (200, 201, 409, 422)


@FUZZ
@given(raw=st.binary(max_size=300))
def test_put_never_fails_on_arbitrary_bytes(client: FlaskClient, raw: bytes) -> None:
    response = client.put(
        "/api/v1/runs/fuzz", data=raw, content_type="application/json", headers=AUTH
    )
    _assert_client_answer(response)
    assert response.status_code == 422


def test_a_fuzzed_agent_still_accepts_a_valid_run(client: FlaskClient) -> None:
    # Sanity check for the strategies above: the well-formed neighbour of what they send.
    response = client.put("/api/v1/runs/ok", json=run_body(time.time() + 3600), headers=AUTH)
    assert response.status_code == 201
