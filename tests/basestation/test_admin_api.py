"""The admin endpoints through Flask's test client: battery, manual control, e-stop, usage log."""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

import pytest
from flask.testing import FlaskClient

from basestation.runtime import AgentRuntime
from tests.basestation.conftest import run_body

Drive = Callable[[float, float], float]


def _control(client: FlaskClient, auth: dict[str, str], **body: Any) -> Any:
    payload: dict[str, Any] = {"user": "admin", "velocity_mps": 0.5, "direction": "cw"}
    payload.update(body)
    return client.post("/api/v1/control", json=payload, headers=auth)


# -- battery ---------------------------------------------------------------------------------------


def test_battery_is_null_before_the_first_frame(client: FlaskClient, auth: dict[str, str]) -> None:
    response = client.get("/api/v1/battery", headers=auth)
    assert response.status_code == 200
    assert response.json == {
        "filtered_v": None,
        "raw_v": None,
        "window": 9,
        "age_s": None,
        "low_battery_v": 50.0,
        "low": False,
    }


def test_battery_reports_the_filtered_and_the_raw_voltage(
    client: FlaskClient, auth: dict[str, str], drive: Drive
) -> None:
    now_s = time.time()
    drive(now_s - 1.0, now_s)
    body = client.get("/api/v1/battery", headers=auth).json
    assert body is not None
    assert body["filtered_v"] == pytest.approx(60.0, abs=0.1)
    assert body["raw_v"] == pytest.approx(60.0, abs=0.1)
    assert body["filtered_v"] != body["raw_v"]  # the raw reading carries noise
    assert 0 <= body["age_s"] < 5.0
    assert body["low"] is False


# -- manual control --------------------------------------------------------------------------------


def test_control_drives_the_robot_by_hand(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime
) -> None:
    response = _control(client, auth, velocity_mps=0.4, direction="ccw", ttl_s=2.5)
    assert response.status_code == 200
    body = response.json
    assert body is not None
    assert body["aborted_run"] is None
    manual = body["manual"]
    assert (manual["user"], manual["velocity_mps"], manual["direction"]) == ("admin", 0.4, "ccw")
    assert 2.0 < manual["ttl_s"] <= 2.5
    assert manual["expires_at"].endswith("Z")
    status = client.get("/api/v1/status", headers=auth).json
    assert status is not None
    assert status["manual"]["user"] == "admin"
    assert runtime.manager.manual(time.time()) is not None


def test_control_uses_a_one_second_dead_man_by_default(
    client: FlaskClient, auth: dict[str, str]
) -> None:
    body = _control(client, auth).json
    assert body is not None
    assert 0.5 < body["manual"]["ttl_s"] <= 1.0


def test_control_with_velocity_zero_ends_manual_drive(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime
) -> None:
    _control(client, auth)
    response = _control(client, auth, velocity_mps=0)
    assert response.status_code == 200
    assert (response.json["manual"], response.json["aborted_run"]) == (None, None)
    assert runtime.manager.manual(time.time()) is None


def test_control_answers_with_the_robots_motion_as_the_status_reads_it(
    client: FlaskClient, auth: dict[str, str], drive: Drive
) -> None:
    """A console holding a drive button follows the robot from the answers alone."""
    before = _control(client, auth).json
    assert before is not None
    # No telemetry yet: nothing measured, the link down.
    assert before["robot"]["velocity_mps"] is None
    assert before["link"]["state"] == "down"
    now_s = time.time()
    drive(now_s - 1.0, now_s)
    answer = _control(client, auth).json
    status = client.get("/api/v1/status", headers=auth).json
    assert answer is not None
    assert status is not None
    assert answer["robot"] == status["robot"]
    assert answer["robot"]["velocity_mps"] > 0
    assert answer["robot"]["commanded_direction"] == "cw"
    assert answer["link"]["state"] == status["link"]["state"] == "up"
    assert before["clock"] < answer["clock"] <= status["clock"]


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"velocity_mps": -0.1}, "velocity_mps"),
        ({"velocity_mps": 2.5}, "velocity_mps"),  # above AGENT_MAX_VELOCITY_MPS
        ({"velocity_mps": "fast"}, "velocity_mps"),
        ({"velocity_mps": True}, "velocity_mps"),
        ({"direction": "up"}, "direction"),
        ({"ttl_s": 0}, "ttl_s"),
        ({"ttl_s": 11}, "ttl_s"),
        ({"force": "yes"}, "force"),
        ({"user": " "}, "user"),
        ({"user": "x" * 151}, "user"),
        ({"extra": 1}, "extra"),
    ],
)
def test_control_rejects_an_invalid_field_with_422_naming_it(
    client: FlaskClient,
    auth: dict[str, str],
    runtime: AgentRuntime,
    body: dict[str, Any],
    field: str,
) -> None:
    response = _control(client, auth, **body)
    assert response.status_code == 422
    assert response.json is not None
    assert list(response.json["fields"]) == [field]
    assert runtime.manager.manual(time.time()) is None


def test_control_needs_user_velocity_and_direction(
    client: FlaskClient, auth: dict[str, str]
) -> None:
    response = client.post("/api/v1/control", json={}, headers=auth)
    assert response.status_code == 422
    assert response.json is not None
    assert set(response.json["fields"]) == {"user", "velocity_mps", "direction"}


def test_control_refuses_a_body_that_is_not_json(client: FlaskClient, auth: dict[str, str]) -> None:
    response = client.post("/api/v1/control", data="velocity=1", headers=auth)
    assert response.status_code == 415
    response = client.post(
        "/api/v1/control", data="{", content_type="application/json", headers=auth
    )
    assert response.status_code == 422


def test_control_is_refused_while_a_run_holds_the_robot_unless_forced(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime, drive: Drive
) -> None:
    start_s = time.time() + 0.1
    client.put("/api/v1/runs/run-1", json=run_body(start_s), headers=auth)
    drive(start_s, start_s + 1.0)
    response = _control(client, auth)
    assert response.status_code == 409
    assert response.json is not None
    assert response.json["conflict"] == "robot_busy"
    assert "run-1" in response.json["detail"]
    assert client.get("/api/v1/runs/run-1", headers=auth).json["state"] == "running"  # type: ignore[index]

    response = _control(client, auth, force=True)
    assert response.status_code == 200
    assert response.json is not None
    assert response.json["aborted_run"] == "run-1"
    run = client.get("/api/v1/runs/run-1", headers=auth).json
    assert run is not None
    assert run["state"] == "aborted"
    assert run["reason"] == "aborted: admin took manual control"


# -- e-stop ---------------------------------------------------------------------------------------


def test_stop_latches_until_released(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime
) -> None:
    response = client.post("/api/v1/stop", headers=auth)
    assert response.status_code == 200
    body = response.json
    assert body is not None
    assert body["estop"]["latched"] is True
    assert body["estop"]["reason"] == "emergency stop through the API"
    assert body["aborted_run"] is None
    since = body["estop"]["since"]

    again = client.post("/api/v1/stop", json={"reason": "again", "user": "bob"}, headers=auth)
    assert again.json is not None
    assert again.json["estop"]["since"] == since  # still the first latch

    status = client.get("/api/v1/status", headers=auth).json
    assert status is not None
    assert status["estop"]["latched"] is True
    refused = _control(client, auth)
    assert refused.status_code == 409
    assert refused.json is not None
    assert refused.json["conflict"] == "estop_latched"

    released = client.post("/api/v1/stop/release", json={"user": "bob"}, headers=auth)
    assert released.status_code == 200
    assert released.json == {
        "estop": {"latched": False, "since": None, "reason": None},
        "released": True,
    }
    again = client.post("/api/v1/stop/release", headers=auth)
    assert again.json is not None
    assert again.json["released"] is False
    assert runtime.manager.estop is None
    assert _control(client, auth).status_code == 200


def test_stop_records_who_and_why(client: FlaskClient, auth: dict[str, str]) -> None:
    body = client.post(
        "/api/v1/stop", json={"reason": "person on the roof", "user": "carol"}, headers=auth
    ).json
    assert body is not None
    assert body["estop"]["reason"] == "person on the roof (by carol)"


def test_stop_aborts_the_running_run(
    client: FlaskClient, auth: dict[str, str], drive: Drive
) -> None:
    start_s = time.time() + 0.1
    client.put("/api/v1/runs/run-1", json=run_body(start_s), headers=auth)
    next_s = drive(start_s, start_s + 1.0)
    body = client.post("/api/v1/stop", headers=auth).json
    assert body is not None
    assert body["aborted_run"] == "run-1"
    drive(next_s, next_s + 1.0)
    run = client.get("/api/v1/runs/run-1", headers=auth).json
    assert run is not None
    assert run["state"] == "aborted"
    assert run["reason"] == "emergency stop: emergency stop through the API"


@pytest.mark.parametrize("body", [{"reason": "x"}, {"user": ""}, [1], "released"])
def test_release_rejects_invalid_bodies_and_changes_nothing(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime, body: Any
) -> None:
    client.post("/api/v1/stop", headers=auth)
    response = client.post("/api/v1/stop/release", json=body, headers=auth)
    assert response.status_code == 422
    assert runtime.manager.estop is not None


# -- the daily usage log ---------------------------------------------------------------------------


def _day(epoch_s: float) -> str:
    return datetime.fromtimestamp(epoch_s, tz=UTC).date().isoformat()


def test_the_day_log_lists_runs_and_manual_sessions_with_user_title_start_and_end(
    client: FlaskClient, auth: dict[str, str], drive: Drive
) -> None:
    _control(client, auth, user="itboss", ttl_s=1.0)
    start_s = time.time() + 1.0
    segments = [{"velocity_mps": 0.3, "direction": "cw", "duration_s": 0.5}]
    client.put(
        "/api/v1/runs/run-1",
        json=run_body(start_s, window_s=3.0, segments=segments, owner="raalmeida", title="sweep"),
        headers=auth,
    )
    drive(start_s, start_s + 2.5)

    response = client.get(f"/api/v1/logs/{_day(start_s)}", headers=auth)
    assert response.status_code == 200
    body = response.json
    assert body is not None
    assert body["date"] == _day(start_s)
    assert body["timezone"] == "UTC"
    manual_entry, run_entry = body["entries"]
    assert run_entry["user"] == "raalmeida"
    assert run_entry["title"] == "sweep"
    assert run_entry["kind"] == "run"
    assert run_entry["run_id"] == "run-1"
    assert run_entry["state"] == "completed"
    assert run_entry["start"] < run_entry["end"]
    assert manual_entry["user"] == "itboss"
    assert manual_entry["title"] == "manual control"
    assert manual_entry["kind"] == "manual"
    assert manual_entry["start"] < manual_entry["end"]


def test_the_day_log_comes_as_csv_on_request(
    client: FlaskClient, auth: dict[str, str], drive: Drive
) -> None:
    _control(client, auth, user="itboss")
    response = client.get(
        f"/api/v1/logs/{_day(time.time())}", headers={**auth, "Accept": "text/csv"}
    )
    assert response.status_code == 200
    assert response.mimetype == "text/csv"
    rows = list(csv.reader(io.StringIO(response.get_data(as_text=True))))
    assert rows[0] == ["user", "title", "start", "end", "kind", "run_id", "state"]
    assert rows[1][:2] == ["itboss", "manual control"]
    assert rows[1][5:] == ["", ""]


def test_the_day_log_of_a_quiet_day_is_empty(client: FlaskClient, auth: dict[str, str]) -> None:
    response = client.get("/api/v1/logs/2019-12-17", headers=auth)
    assert response.status_code == 200
    assert response.json == {"date": "2019-12-17", "timezone": "UTC", "entries": []}


@pytest.mark.parametrize("day", ["2019-02-30", "2019-13-01", "19-12-17", "2019-1-07", "today"])
def test_the_day_log_rejects_what_is_not_a_date(
    client: FlaskClient, auth: dict[str, str], day: str
) -> None:
    response = client.get(f"/api/v1/logs/{day}", headers=auth)
    assert response.status_code == 422
    assert response.json is not None
    assert list(response.json["fields"]) == ["date"]


@pytest.mark.parametrize(
    "path",
    [
        "/api/v1/logs/../../etc/passwd",
        "/api/v1/logs/..%2F..%2Fetc%2Fpasswd",
        "/api/v1/logs/%2e%2e%2f%2e%2e%2fetc%2fpasswd",
        "/api/v1/logs/..%252F..%252Fetc%252Fpasswd",
        "/api/v1/logs/2019-12-17%2F..%2F..%2Fetc%2Fpasswd",
        "/api/v1/logs/%00",
        "/api/v1/logs/..",
        "/api/v1/logs/",
    ],
)
def test_the_day_log_refuses_path_traversal(
    client: FlaskClient, auth: dict[str, str], path: str
) -> None:
    response = client.get(path, headers=auth)
    assert response.status_code in (404, 422)
    assert response.is_json
    assert "root:" not in response.get_data(as_text=True)
