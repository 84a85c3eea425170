"""The runs API through Flask's test client, with the manager ticked by hand."""

from __future__ import annotations

import csv
import io
import json
import threading
import time
from collections.abc import Callable
from datetime import datetime, timedelta, timezone
from typing import Any

import pytest
from flask import Flask
from flask.testing import FlaskClient

from basestation.runtime import AgentRuntime
from tests.basestation.conftest import iso, run_body

Drive = Callable[[float, float], float]


def _put(client: FlaskClient, auth: dict[str, str], run_id: str, body: Any) -> Any:
    return client.put(f"/api/v1/runs/{run_id}", json=body, headers=auth)


def _run_ids(runtime: AgentRuntime) -> list[str]:
    return [record.id for record, _ in runtime.store.list_runs()]


# -- PUT ----------------------------------------------------------------------------------------


def test_it_stages_a_new_run_and_answers_201_with_the_run(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    response = _put(client, auth, "run-1", run_body(soon))
    assert response.status_code == 201
    assert response.headers["Location"].endswith("/api/v1/runs/run-1")
    run = response.json
    assert run is not None
    assert run["id"] == "run-1"
    assert run["state"] == "staged"
    assert run["reason"] is None
    assert run["owner"] == "alice"
    assert run["title"] == "two-way sweep"
    assert run["start_at"].endswith("Z")
    assert run["segments"] == [
        {"velocity_mps": 0.5, "direction": "cw", "duration_s": 3.0},
        {"velocity_mps": 0.8, "direction": "ccw", "duration_s": 3.0},
    ]
    assert run["limits"] == {"max_velocity_mps": 1.0, "max_accel_mps2": 1.0}
    assert (run["sample_count"], run["first_seq"], run["last_seq"]) == (0, None, None)


def test_every_run_answer_names_the_rail_length_its_track_wraps_at(
    client: FlaskClient, auth: dict[str, str], soon: float, runtime: AgentRuntime
) -> None:
    expected_m = runtime.manager.rail_length_m
    assert expected_m == runtime.config.rail_length_m  # no rail file in these tests
    put = _put(client, auth, "run-1", run_body(soon)).json
    got = client.get("/api/v1/runs/run-1", headers=auth).json
    listed = client.get("/api/v1/runs", headers=auth).json
    withdrawn = client.delete("/api/v1/runs/run-1", headers=auth).json
    for answer in (put, got, listed, withdrawn):
        assert answer is not None
    assert [put["rail_length_m"], got["rail_length_m"], withdrawn["rail_length_m"]] == [
        expected_m
    ] * 3
    assert listed["runs"][0]["rail_length_m"] == expected_m


def test_it_answers_200_to_the_same_body_again(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    first = _put(client, auth, "run-1", run_body(soon))
    again = _put(client, auth, "run-1", run_body(soon))
    assert again.status_code == 200
    assert again.json == first.json


def test_it_compares_bodies_by_meaning_not_text(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    assert _put(client, auth, "run-1", run_body(soon)).status_code == 201
    body = run_body(soon)
    # Same instants in another zone, integers for floats, keys in another order.
    body["start_at"] = iso(soon).replace("+00:00", "Z")
    plus_one = timezone(timedelta(hours=1))
    body["end_at"] = datetime.fromtimestamp(soon + 10.0, tz=plus_one).isoformat()
    assert body["end_at"].endswith("+01:00")
    body["segments"][0]["duration_s"] = 3
    body = dict(reversed(list(body.items())))
    raw = json.dumps(body, indent=4)
    response = client.put(
        "/api/v1/runs/run-1", data=raw, content_type="application/json", headers=auth
    )
    assert response.status_code == 200


def test_it_rejects_a_different_body_for_an_existing_run(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime, soon: float
) -> None:
    original = _put(client, auth, "run-1", run_body(soon)).json
    response = _put(client, auth, "run-1", run_body(soon, title="something else"))
    assert response.status_code == 409
    assert response.json is not None
    assert response.json["error"] == "conflict"
    assert response.json["conflict"] == "body_differs"
    assert client.get("/api/v1/runs/run-1", headers=auth).json == original


def test_it_rejects_a_window_overlapping_a_staged_run(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime, soon: float
) -> None:
    assert _put(client, auth, "run-1", run_body(soon)).status_code == 201
    response = _put(client, auth, "run-2", run_body(soon + 9.0))
    assert response.status_code == 409
    assert response.json is not None
    assert response.json["conflict"] == "window_overlaps"
    assert "run-1" in response.json["detail"]
    assert _run_ids(runtime) == ["run-1"]


def test_it_accepts_back_to_back_windows(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    assert _put(client, auth, "run-1", run_body(soon)).status_code == 201
    assert _put(client, auth, "run-2", run_body(soon + 10.0)).status_code == 201
    assert _put(client, auth, "run-0", run_body(soon - 10.0)).status_code == 201


def test_it_lets_a_new_run_take_the_window_of_a_cancelled_one(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    assert _put(client, auth, "run-1", run_body(soon)).status_code == 201
    assert client.delete("/api/v1/runs/run-1", headers=auth).status_code == 200
    assert _put(client, auth, "run-2", run_body(soon)).status_code == 201


def _with(body: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """``body`` with the field at dotted ``path`` set to ``value`` (``...`` deletes it)."""
    target: Any = body
    keys: list[Any] = [int(k) if k.isdigit() else k for k in path.split(".")]
    for key in keys[:-1]:
        target = target[key]
    if value is ...:
        del target[keys[-1]]
    else:
        target[keys[-1]] = value
    return body


INVALID_FIELDS: list[tuple[str, Any, str]] = [
    # (dotted path in the body, value or ... to delete, field named in the answer)
    ("owner", ..., "owner"),
    ("owner", "", "owner"),
    ("owner", 42, "owner"),
    ("owner", "x" * 151, "owner"),
    ("title", None, "title"),
    ("title", "\ud800", "title"),
    ("start_at", ..., "start_at"),
    ("start_at", "2030-01-01T10:00:00", "start_at"),
    ("start_at", "next tuesday", "start_at"),
    ("start_at", 1893456000, "start_at"),
    ("end_at", "2030-13-01T10:00:00Z", "end_at"),
    ("segments", [], "segments"),
    ("segments", {"velocity_mps": 1}, "segments"),
    ("segments.0", "fast", "segments[0]"),
    ("segments.0.velocity_mps", -0.1, "segments[0].velocity_mps"),
    ("segments.0.velocity_mps", "0.5", "segments[0].velocity_mps"),
    ("segments.0.velocity_mps", True, "segments[0].velocity_mps"),
    ("segments.0.velocity_mps", 1e400, "segments[0].velocity_mps"),
    ("segments.0.velocity_mps", 10**400, "segments[0].velocity_mps"),
    ("segments.0.velocity_mps", ..., "segments[0].velocity_mps"),
    ("segments.1.direction", "left", "segments[1].direction"),
    ("segments.1.direction", "CW", "segments[1].direction"),
    ("segments.1.direction", ..., "segments[1].direction"),
    ("segments.1.duration_s", 0, "segments[1].duration_s"),
    ("segments.1.duration_s", -3, "segments[1].duration_s"),
    ("segments.1.speed", 1.0, "segments[1].speed"),
    ("limits", ..., "limits"),
    ("limits", [1, 2], "limits"),
    ("limits.max_accel_mps2", 0, "limits.max_accel_mps2"),
    ("limits.max_velocity_mps", None, "limits.max_velocity_mps"),
    ("limits.jerk", 1, "limits.jerk"),
    ("colour", "red", "colour"),
]


@pytest.mark.parametrize(
    ("path", "value", "field"),
    INVALID_FIELDS,
    ids=[f"{p}={v!r:.20}" for p, v, _ in INVALID_FIELDS],
)
def test_it_rejects_an_invalid_field_with_422_naming_it(
    client: FlaskClient,
    auth: dict[str, str],
    runtime: AgentRuntime,
    soon: float,
    path: str,
    value: Any,
    field: str,
) -> None:
    body = _with(run_body(soon), path, value)
    # json.dumps would refuse 1e400; send the literal text the portal could send.
    raw = json.dumps(body).replace("Infinity", "1e400")
    response = client.put(
        "/api/v1/runs/run-1", data=raw, content_type="application/json", headers=auth
    )
    assert response.status_code == 422, response.json
    assert response.json is not None
    assert response.json["error"] == "invalid"
    assert field in response.json["fields"], response.json["fields"]
    assert all(isinstance(m, str) and m for m in response.json["fields"][field])
    assert _run_ids(runtime) == []


def test_it_rejects_a_velocity_above_the_robots_maximum(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    body = run_body(soon, max_velocity_mps=5.0)  # the run allows it, the agent (2.0) does not
    body["segments"][0]["velocity_mps"] = 2.5
    response = _put(client, auth, "run-1", body)
    assert response.status_code == 422
    assert response.json is not None
    assert "robot's maximum" in response.json["fields"]["segments[0].velocity_mps"][0]


def test_it_rejects_a_velocity_above_the_runs_own_limit(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    body = run_body(soon, max_velocity_mps=0.6)
    response = _put(client, auth, "run-1", body)
    assert response.status_code == 422
    assert response.json is not None
    assert "run's max_velocity_mps" in response.json["fields"]["segments[1].velocity_mps"][0]


def test_it_rejects_a_program_longer_than_the_window(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    response = _put(client, auth, "run-1", run_body(soon, window_s=5.0))
    assert response.status_code == 422
    assert response.json is not None
    assert "longer than" in response.json["fields"]["segments"][0]


def test_it_rejects_an_end_before_the_start(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    body = run_body(soon)
    body["end_at"] = body["start_at"]
    response = _put(client, auth, "run-1", body)
    assert response.status_code == 422
    assert response.json is not None
    assert response.json["fields"]["end_at"] == ["must be after start_at"]


def test_it_rejects_an_end_in_the_past(client: FlaskClient, auth: dict[str, str]) -> None:
    response = _put(client, auth, "run-1", run_body(time.time() - 60.0, window_s=30.0))
    assert response.status_code == 422
    assert response.json is not None
    assert response.json["fields"]["end_at"] == ["is in the past"]


def test_it_rejects_too_many_segments(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    segments = [{"velocity_mps": 0.1, "direction": "cw", "duration_s": 0.1}] * 101
    response = _put(client, auth, "run-1", run_body(soon, segments=segments, window_s=60))
    assert response.status_code == 422
    assert response.json is not None
    assert "segments" in response.json["fields"]


def test_it_accepts_exactly_one_hundred_segments(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    segments = [{"velocity_mps": 0.1, "direction": "cw", "duration_s": 0.1}] * 100
    response = _put(client, auth, "run-1", run_body(soon, segments=segments, window_s=60))
    assert response.status_code == 201


@pytest.mark.parametrize(
    "raw",
    [b"not json", b"[1, 2", b'{"owner": NaN}', b"\xff\xfe", b"[]", b"null", b"[" * 50_000],
)
def test_it_rejects_a_body_that_is_not_a_json_object(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime, raw: bytes
) -> None:
    response = client.put(
        "/api/v1/runs/run-1", data=raw, content_type="application/json", headers=auth
    )
    assert response.status_code == 422
    assert response.json is not None
    assert "body" in response.json["fields"]
    assert _run_ids(runtime) == []


def test_it_refuses_a_body_that_is_not_json_by_content_type(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    response = client.put(
        "/api/v1/runs/run-1",
        data=json.dumps(run_body(soon)),
        content_type="text/plain",
        headers=auth,
    )
    assert response.status_code == 415
    assert response.json is not None
    assert response.json["error"] == "unsupported_media_type"


def test_it_refuses_a_body_over_64_kib(client: FlaskClient, auth: dict[str, str]) -> None:
    response = client.put(
        "/api/v1/runs/run-1",
        data=b'{"owner": "' + b"x" * 70_000 + b'"}',
        content_type="application/json",
        headers=auth,
    )
    assert response.status_code == 413
    assert response.json is not None
    assert response.json["error"] == "request_entity_too_large"


@pytest.mark.parametrize("run_id", ["a.b", "x" * 65, "run 1", "r%C3%A9", "..", "-;rm"])
def test_it_rejects_run_ids_outside_the_allowed_alphabet(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime, soon: float, run_id: str
) -> None:
    response = _put(client, auth, run_id, run_body(soon))
    assert response.status_code in (404, 422)
    assert response.is_json
    assert _run_ids(runtime) == []
    assert client.get(f"/api/v1/runs/{run_id}", headers=auth).status_code == 404


def test_it_accepts_the_longest_allowed_run_id(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    run_id = "A-z_9" + "x" * 59
    assert _put(client, auth, run_id, run_body(soon)).status_code == 201
    assert client.get(f"/api/v1/runs/{run_id}", headers=auth).status_code == 200


def test_it_answers_200_to_a_repeat_after_the_window_has_passed(
    client: FlaskClient, auth: dict[str, str], drive: Drive
) -> None:
    # The portal may re-send a PUT late (a retried task); the run exists, so 200, not 422.
    start_s = time.time() + 0.2
    segments = [{"velocity_mps": 0.1, "direction": "cw", "duration_s": 0.2}]
    body = run_body(start_s, window_s=0.4, segments=segments)
    assert _put(client, auth, "run-1", body).status_code == 201
    drive(start_s - 0.1, start_s + 0.5)
    time.sleep(max(0.0, start_s + 0.45 - time.time()))
    response = _put(client, auth, "run-1", body)
    assert response.status_code == 200
    assert response.json is not None
    assert response.json["state"] == "completed"


# -- GET, list ------------------------------------------------------------------------------------


def test_it_lists_runs_newest_first_and_filters_by_state(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    for index, run_id in enumerate(["a", "b", "c"]):
        assert _put(client, auth, run_id, run_body(soon + 20 * index)).status_code == 201
    client.delete("/api/v1/runs/b", headers=auth)
    response = client.get("/api/v1/runs", headers=auth)
    assert response.status_code == 200
    assert response.json is not None
    assert [r["id"] for r in response.json["runs"]] == ["c", "b", "a"]
    staged = client.get("/api/v1/runs?state=staged", headers=auth).json
    assert staged is not None
    assert [r["id"] for r in staged["runs"]] == ["c", "a"]
    bad = client.get("/api/v1/runs?state=bogus", headers=auth)
    assert bad.status_code == 422
    assert bad.json is not None
    assert "state" in bad.json["fields"]


def test_it_answers_404_json_for_an_unknown_run(client: FlaskClient, auth: dict[str, str]) -> None:
    for response in (
        client.get("/api/v1/runs/nope", headers=auth),
        client.delete("/api/v1/runs/nope", headers=auth),
        client.get("/api/v1/runs/nope/samples", headers=auth),
    ):
        assert response.status_code == 404
        assert response.json is not None
        assert response.json["error"] == "not_found"


def test_it_answers_json_for_unknown_paths_and_methods(
    client: FlaskClient, auth: dict[str, str]
) -> None:
    missing = client.get("/api/v1/nothing-here", headers=auth)
    assert missing.status_code == 404
    assert missing.json is not None
    assert missing.json["error"] == "not_found"
    wrong = client.post("/api/v1/runs/run-1", headers=auth)
    assert wrong.status_code == 405
    assert wrong.json is not None
    assert wrong.json["error"] == "method_not_allowed"
    assert "PUT" in wrong.headers["Allow"]


def test_it_answers_500_as_json_without_internals(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime
) -> None:
    runtime.store.close()  # every store call now raises
    response = client.get("/api/v1/runs", headers=auth)
    assert response.status_code == 500
    assert response.json == {
        "error": "internal",
        "detail": "The agent failed to handle this request; see the agent's log.",
    }


# -- DELETE ----------------------------------------------------------------------------------------


def test_it_cancels_a_staged_run(client: FlaskClient, auth: dict[str, str], soon: float) -> None:
    _put(client, auth, "run-1", run_body(soon))
    response = client.delete("/api/v1/runs/run-1", headers=auth)
    assert response.status_code == 200
    assert response.json is not None
    assert response.json["state"] == "cancelled"
    assert response.json["reason"]
    assert response.json["ended_at"] is not None


def test_it_refuses_to_withdraw_a_run_that_has_ended(
    client: FlaskClient, auth: dict[str, str], soon: float
) -> None:
    _put(client, auth, "run-1", run_body(soon))
    client.delete("/api/v1/runs/run-1", headers=auth)
    response = client.delete("/api/v1/runs/run-1", headers=auth)
    assert response.status_code == 409
    assert response.json is not None
    assert response.json["conflict"] == "already_ended"


def test_it_aborts_a_running_run_ramps_the_robot_to_zero_and_keeps_its_samples(
    client: FlaskClient,
    auth: dict[str, str],
    runtime: AgentRuntime,
    drive: Drive,
    soon: float,
) -> None:
    _put(client, auth, "run-1", run_body(soon))
    next_s = drive(soon, soon + 2.0)
    assert runtime.store.get_run("run-1").state == "running"  # type: ignore[union-attr]
    response = client.delete("/api/v1/runs/run-1", headers=auth)
    assert response.status_code == 200
    assert response.json is not None
    assert response.json["state"] == "aborted"
    kept = response.json["sample_count"]
    assert kept == 40

    drive(next_s, next_s + 2.0)
    after = client.get("/api/v1/runs/run-1", headers=auth).json
    assert after is not None
    assert after["state"] == "aborted"
    assert after["sample_count"] == kept  # nothing recorded after the abort
    assert runtime.manager.snapshot.current_run is None
    telemetry = runtime.manager.snapshot.telemetry
    assert telemetry is not None
    assert telemetry.velocity_mps == 0.0


# -- samples ---------------------------------------------------------------------------------------


@pytest.fixture
def sixty_samples(client: FlaskClient, auth: dict[str, str], drive: Drive, soon: float) -> str:
    _put(client, auth, "run-1", run_body(soon))
    drive(soon, soon + 3.0)
    return "run-1"


def test_it_pages_through_samples_in_seq_order(
    client: FlaskClient, auth: dict[str, str], sixty_samples: str
) -> None:
    seqs: list[int] = []
    after = 0
    pages = []
    while True:
        response = client.get(
            f"/api/v1/runs/{sixty_samples}/samples?after={after}&limit=25", headers=auth
        )
        assert response.status_code == 200
        page = response.json
        assert page is not None
        assert page["run_id"] == sixty_samples
        assert page["state"] == "running"
        pages.append((len(page["samples"]), page["last_seq"], page["more"]))
        seqs.extend(s["seq"] for s in page["samples"])
        if not page["more"]:
            break
        after = page["last_seq"]
    assert pages == [(25, 25, True), (25, 50, True), (10, 60, False)]
    assert seqs == list(range(1, 61))
    empty = client.get(f"/api/v1/runs/{sixty_samples}/samples?after=60", headers=auth).json
    assert empty == {
        "run_id": sixty_samples,
        "state": "running",
        "samples": [],
        "last_seq": 60,
        "more": False,
    }


def test_it_returns_samples_with_every_field(
    client: FlaskClient, auth: dict[str, str], sixty_samples: str, soon: float
) -> None:
    page = client.get(f"/api/v1/runs/{sixty_samples}/samples?limit=1", headers=auth).json
    assert page is not None
    (sample,) = page["samples"]
    assert set(sample) == {
        "seq",
        "t",
        "segment",
        "commanded_velocity_mps",
        "velocity_mps",
        "direction",
        "battery_v",
        "track_m",
        "fix_quality",
        "lat_deg",
        "lon_deg",
        "grid_id",
        "lap",
    }
    assert sample["seq"] == 1
    # The kinematic model has no GPS: no position, and no lap completed yet.
    assert (sample["fix_quality"], sample["grid_id"], sample["lap"]) == (None, None, 0)
    assert sample["t"] == pytest.approx(soon)
    assert sample["segment"] == 0
    assert sample["commanded_velocity_mps"] == 0.5
    assert sample["direction"] == "cw"
    assert 55.0 < sample["battery_v"] < 61.0


def test_it_serves_the_same_page_as_csv(
    client: FlaskClient, auth: dict[str, str], sixty_samples: str
) -> None:
    url = f"/api/v1/runs/{sixty_samples}/samples?after=10&limit=20"
    as_json = client.get(url, headers=auth).json
    response = client.get(url, headers={**auth, "Accept": "text/csv"})
    assert response.status_code == 200
    assert response.mimetype == "text/csv"
    assert response.headers["X-Last-Seq"] == "30"
    assert response.headers["X-More"] == "true"
    assert "Accept" in response.headers["Vary"]
    rows = list(csv.DictReader(io.StringIO(response.get_data(as_text=True))))
    assert as_json is not None
    assert len(rows) == 20
    for row, sample in zip(rows, as_json["samples"], strict=True):
        assert int(row["seq"]) == sample["seq"]
        assert float(row["t"]) == sample["t"]
        assert float(row["velocity_mps"]) == sample["velocity_mps"]
        assert row["direction"] == sample["direction"]
        assert float(row["track_m"]) == sample["track_m"]


def test_it_writes_an_empty_segment_in_csv_after_the_program(
    client: FlaskClient, auth: dict[str, str], drive: Drive, soon: float
) -> None:
    _put(client, auth, "run-1", run_body(soon))
    drive(soon, soon + 10.0)
    response = client.get(
        "/api/v1/runs/run-1/samples?limit=5000", headers={**auth, "Accept": "text/csv"}
    )
    rows = list(csv.DictReader(io.StringIO(response.get_data(as_text=True))))
    assert rows[0]["segment"] == "0"
    assert rows[-1]["segment"] == ""


@pytest.mark.parametrize(
    ("query", "field"),
    [
        ("after=-1", "after"),
        ("after=abc", "after"),
        ("after=1.5", "after"),
        ("limit=0", "limit"),
        ("limit=5001", "limit"),
        ("limit=", "limit"),
        ("limit=1e3", "limit"),
        ("wait_s=31", "wait_s"),
        ("wait_s=-1", "wait_s"),
        ("wait_s=0.5", "wait_s"),
    ],
)
def test_it_rejects_bad_paging_values(
    client: FlaskClient, auth: dict[str, str], sixty_samples: str, query: str, field: str
) -> None:
    response = client.get(f"/api/v1/runs/{sixty_samples}/samples?{query}", headers=auth)
    assert response.status_code == 422
    assert response.json is not None
    assert field in response.json["fields"]


def test_it_accepts_the_largest_page(
    client: FlaskClient, auth: dict[str, str], sixty_samples: str
) -> None:
    response = client.get(f"/api/v1/runs/{sixty_samples}/samples?limit=5000", headers=auth)
    assert response.status_code == 200
    assert response.json is not None
    assert len(response.json["samples"]) == 60


def _get_in_thread(app_client: FlaskClient, url: str, auth: dict[str, str]) -> Any:
    """Start ``GET url`` on a thread of its own; ``.join()`` then ``.result`` (json, seconds)."""

    class Request(threading.Thread):
        result: tuple[Any, float] | None = None

        def run(self) -> None:
            started = time.monotonic()
            response = app_client.get(url, headers=auth)
            assert response.status_code == 200
            self.result = (response.json, time.monotonic() - started)

    request = Request()
    request.start()
    return request


def test_a_long_poll_answers_with_the_next_sample_as_soon_as_it_is_stored(
    app: Flask, auth: dict[str, str], runtime: AgentRuntime, drive: Drive, soon: float
) -> None:
    client = app.test_client()
    _put(client, auth, "run-1", run_body(soon))
    next_s = drive(soon, soon + 1.0)
    request = _get_in_thread(
        app.test_client(), "/api/v1/runs/run-1/samples?after=20&wait_s=20", auth
    )
    # Wait until it waits (or has answered), then store the next sample: one tick.
    deadline = time.monotonic() + 10
    while runtime.store.waiting == 0 and request.is_alive() and time.monotonic() < deadline:
        time.sleep(0.01)
    drive(next_s, next_s + 0.01)
    request.join(timeout=15)
    assert request.result is not None
    page, elapsed_s = request.result
    assert [s["seq"] for s in page["samples"]] == [21]
    assert page["state"] == "running"
    assert elapsed_s < 10  # woken by the commit, not by its 20 s deadline


def test_a_long_poll_on_a_run_that_ended_answers_at_once_with_its_state(
    client: FlaskClient, auth: dict[str, str], runtime: AgentRuntime, drive: Drive, soon: float
) -> None:
    _put(client, auth, "run-1", run_body(soon))
    drive(soon, soon + 1.0)
    client.delete("/api/v1/runs/run-1", headers=auth)
    started = time.monotonic()
    page = client.get("/api/v1/runs/run-1/samples?after=20&wait_s=30", headers=auth).json
    assert time.monotonic() - started < 5
    assert page is not None
    assert (page["state"], page["samples"], page["last_seq"]) == ("aborted", [], 20)


def test_a_long_poll_wakes_when_the_run_ends_without_another_sample(
    app: Flask, auth: dict[str, str], runtime: AgentRuntime, drive: Drive, soon: float
) -> None:
    client = app.test_client()
    _put(client, auth, "run-1", run_body(soon))
    drive(soon, soon + 1.0)
    request = _get_in_thread(
        app.test_client(), "/api/v1/runs/run-1/samples?after=20&wait_s=20", auth
    )
    deadline = time.monotonic() + 10
    while runtime.store.waiting == 0 and request.is_alive() and time.monotonic() < deadline:
        time.sleep(0.01)
    client.delete("/api/v1/runs/run-1", headers=auth)
    request.join(timeout=15)
    assert request.result is not None
    page, elapsed_s = request.result
    assert (page["state"], page["samples"]) == ("aborted", [])
    assert elapsed_s < 10


def test_a_long_poll_with_nothing_new_answers_an_empty_page_at_its_deadline(
    client: FlaskClient, auth: dict[str, str], sixty_samples: str
) -> None:
    started = time.monotonic()
    page = client.get(f"/api/v1/runs/{sixty_samples}/samples?after=60&wait_s=1", headers=auth)
    assert time.monotonic() - started >= 1.0
    assert page.json is not None
    assert (page.json["samples"], page.json["last_seq"], page.json["more"]) == ([], 60, False)


# -- status ----------------------------------------------------------------------------------------


def test_it_reports_status_with_the_current_run(
    client: FlaskClient, auth: dict[str, str], drive: Drive, runtime: AgentRuntime
) -> None:
    start_s = time.time() + 0.2
    _put(client, auth, "run-1", run_body(start_s))
    drive(start_s - 1.0, time.time() + 0.5)
    status = client.get("/api/v1/status", headers=auth).json
    assert status is not None
    assert status["resource"] == "mobile-1"
    assert status["version"]
    assert status["clock"] == pytest.approx(time.time(), abs=5.0)
    assert status["current_run"] == "run-1"
    assert 55.0 < status["battery_v"] < 61.0
    assert status["robot"]["direction"] == "cw"
    assert status["robot"]["velocity_mps"] > 0
    assert 0.0 <= status["robot"]["track_m"] < 120.0
    assert status["link"]["state"] == "up"
    assert status["control"]["hz"] == 20.0
    assert status["control"]["ticks"] > 0
    assert status["control"]["late_ticks"] == 0


def test_it_reports_the_link_down_before_any_telemetry(
    client: FlaskClient, auth: dict[str, str]
) -> None:
    status = client.get("/api/v1/status", headers=auth).json
    assert status is not None
    assert status["link"] == {"state": "down", "age_s": None, "loss_pct": None, "rssi_dbm": None}
    assert status["current_run"] is None
    assert status["battery_v"] is None
