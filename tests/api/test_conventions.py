"""The API's conventions: one error envelope, 401 with WWW-Authenticate, JSON 404 and 405,
input held to the schema's types, pagination, throttles, the audit log, and a schema that
states all of it."""

from __future__ import annotations

from datetime import timedelta

import pytest
import redis
from django.utils import timezone
from rest_framework.test import APIClient

from core.audit.services import audit_record
from portal.runs.services.reservations import reservation_create
from tests.factories import ExperimentFactory, api_token

pytestmark = pytest.mark.django_db

SEGMENT = {"velocity_mps": 0.5, "direction": "cw", "duration_s": 2}


def _is_envelope(body: dict, code: str) -> None:
    assert body["error"] == code, body
    assert isinstance(body["detail"], str)
    assert body["detail"]
    assert set(body) <= {"error", "detail", "fields"}


@pytest.mark.parametrize("method", ["get", "post", "patch", "delete"])
@pytest.mark.parametrize("path", ["/api/v1/nothing/", "/api/v1/runs", "/api/v2/runs/", "/api/"])
def test_unknown_paths_under_api_answer_a_json_404(client, method, path):
    response = getattr(client, method)(path)
    assert response.status_code == 404
    assert response["Content-Type"] == "application/json"
    _is_envelope(response.json(), "not_found")


def test_a_method_an_endpoint_lacks_is_a_json_405_with_allow(api):
    response = api.put("/api/v1/runs/", {}, format="json")
    assert response.status_code == 405
    assert response["Allow"] == "GET, HEAD, OPTIONS"
    _is_envelope(response.json(), "method_not_allowed")


@pytest.mark.parametrize("idempotency_key", [None, "big-body-1"])
def test_a_body_over_the_limit_is_a_json_413_naming_the_limit(api, settings, idempotency_key):
    settings.DATA_UPLOAD_MAX_MEMORY_SIZE = 1_000_000
    body = b'{"title": "' + b"x" * (10 * 2**20) + b'", "segments": []}'
    headers = {"HTTP_X_IDEMPOTENCY_KEY": idempotency_key} if idempotency_key else {}
    response = api.generic(
        "POST", "/api/v1/reservations/", body, content_type="application/json", **headers
    )
    assert response.status_code == 413
    assert response["Content-Type"] == "application/json"
    _is_envelope(response.json(), "request_entity_too_large")
    assert "1000000 bytes" in response.json()["detail"]
    # Under the limit the same endpoint reads the body (and finds it wanting).
    small = api.generic("POST", "/api/v1/reservations/", b"{}", content_type="application/json")
    assert small.status_code == 400


def test_missing_or_refused_credentials_get_401_and_how_to_authenticate(owner):
    client = APIClient()
    missing = client.get("/api/v1/runs/")
    assert missing.status_code == 401
    assert missing["WWW-Authenticate"] == "Token"
    _is_envelope(missing.json(), "not_authenticated")
    refused = client.get("/api/v1/runs/", HTTP_AUTHORIZATION="Token not-a-key")
    assert refused.status_code == 401
    assert refused["WWW-Authenticate"] == "Token"
    _is_envelope(refused.json(), "authentication_failed")
    token = api_token(owner)
    assert client.get("/api/v1/runs/", HTTP_AUTHORIZATION=f"Token {token}").status_code == 200


def test_an_experimenter_on_an_admins_endpoint_gets_403_in_the_envelope(api):
    response = api.get("/api/v1/audit/")
    assert response.status_code == 403
    _is_envelope(response.json(), "permission_denied")


def test_field_errors_name_nested_fields_by_dotted_paths(api, mobile):
    response = api.post(
        "/api/v1/experiments/",
        {"title": "x", "segments": [SEGMENT, {"velocity_mps": -1, "direction": "up"}]},
        format="json",
    )
    assert response.status_code == 400
    body = response.json()
    _is_envelope(body, "invalid")
    assert set(body["fields"]) == {
        "segments.1.velocity_mps",
        "segments.1.direction",
        "segments.1.duration_s",
    }
    assert all(isinstance(m, str) for ms in body["fields"].values() for m in ms)


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"title": 5, "segments": [SEGMENT]}, "title"),
        (
            {"title": "x", "segments": [{**SEGMENT, "velocity_mps": "0.5"}]},
            "segments.0.velocity_mps",
        ),
        ({"title": "x", "segments": [{**SEGMENT, "duration_s": True}]}, "segments.0.duration_s"),
        ({"title": "x", "segments": [{**SEGMENT, "speed": 1}]}, "segments.0.speed"),
        ({"title": "x", "segments": []}, "segments"),
        ({"title": "x", "segments": [{**SEGMENT, "duration_s": 0}]}, "segments.0.duration_s"),
        ({"title": "  ", "segments": [SEGMENT]}, "title"),
        ({"title": "a\x00b", "segments": [SEGMENT]}, "title"),
    ],
)
def test_a_json_body_must_have_the_schemas_types_and_keys(api, mobile, body, field):
    response = api.post("/api/v1/experiments/", body, format="json")
    assert response.status_code == 400, response.json()
    assert field in response.json()["fields"]


def test_names_with_nul_characters_are_refused_not_looked_up(api, mobile):
    start = timezone.now() + timedelta(hours=1)
    response = api.post(
        "/api/v1/reservations/check/",
        {
            "resources": ["mobile\x00"],
            "start_at": start.isoformat(),
            "end_at": (start + timedelta(minutes=5)).isoformat(),
        },
        format="json",
    )
    assert response.status_code == 400
    assert "resources.0" in response.json()["fields"]


@pytest.mark.parametrize(
    "query",
    [
        "limit=1.0",
        "limit=0",
        "limit=501",
        "offset=-1",
        "offset=x",
        "state=",
        "state=lost",
    ],
)
def test_query_values_must_be_spelled_as_their_type(api, query):
    response = api.get(f"/api/v1/runs/?{query}")
    assert response.status_code == 400, query
    assert set(response.json()["fields"]) == {query.split("=")[0]}


@pytest.mark.parametrize(
    ("start", "accepted"),
    [
        ("2026-05-01T10:00:00Z", True),
        ("2026-05-01t10:00:00.123456789z", True),
        ("2026-06-30T23:59:60+01:00", True),
        ("2026-05-01", False),
        ("20260501T100000Z", False),
        ("2026-05-01T10:00:00", False),
        ("2026-05-01T10:00:00+0100", False),
    ],
)
def test_instants_are_rfc3339_as_the_schema_says(api, start, accepted):
    response = api.get(
        "/api/v1/reservations/busy/", {"start": start, "end": "2026-07-02T00:00:00Z"}
    )
    assert response.status_code == (200 if accepted else 400), response.json()


def test_lists_come_in_pages_that_a_client_follows_to_the_end(api, owner):
    for i in range(5):
        ExperimentFactory(owner=owner, title=f"e{i}")
    page = api.get("/api/v1/experiments/?limit=2").json()
    assert (page["count"], page["previous"], len(page["results"])) == (5, None, 2)
    titles = [e["title"] for e in page["results"]]
    while page["next"]:
        page = api.get(page["next"]).json()
        titles += [e["title"] for e in page["results"]]
    assert titles == ["e4", "e3", "e2", "e1", "e0"]  # newest first, each once


def test_an_authenticated_client_over_its_rate_gets_429_with_retry_after(settings, owner):
    settings.API_THROTTLE_USER = "3/minute"
    client = APIClient()
    client.force_authenticate(owner)
    assert [client.get("/api/v1/runs/").status_code for _ in range(3)] == [200] * 3
    refused = client.get("/api/v1/runs/")
    assert refused.status_code == 429
    assert 1 <= int(refused["Retry-After"]) <= 60
    _is_envelope(refused.json(), "throttled")


def test_a_throttle_costs_one_round_trip_to_redis_and_counts_each_user_apart(
    settings, owner, other, monkeypatch
):
    """A request's throttle is one INCR with its EXPIRE in one pipeline: one round trip, not
    a read of a list of timestamps and a write of it back."""
    settings.API_THROTTLE_USER = "1000/minute"
    sent: list[bytes] = []
    real_send = redis.connection.Connection.send_packed_command

    def send(connection, command, check_health=True):
        sent.append(b"".join(command) if isinstance(command, list | tuple) else command)
        return real_send(connection, command, check_health)

    monkeypatch.setattr(redis.connection.Connection, "send_packed_command", send)
    client = APIClient()
    client.force_authenticate(owner)
    assert client.get("/api/v1/runs/").status_code == 200
    # The answer itself may come from the cache too: only the throttle's trips count here.
    throttle = [command for command in sent if b"throttle_" in command]
    assert len(throttle) == 1, sent
    assert b"INCR" in throttle[0]
    assert b"EXPIRE" in throttle[0]
    sent.clear()
    client.force_authenticate(other)
    assert client.get("/api/v1/runs/").status_code == 200
    monkeypatch.undo()
    counters = sorted(redis.Redis.from_url(settings.REDIS_URL).scan_iter("*throttle_user_*"))
    assert len(counters) == 2  # one counter a user


def test_a_throttle_counts_without_redis_too(settings, owner):
    """``make run`` has no Redis: the counter goes through the cache API."""
    settings.CACHES = {"default": {"BACKEND": "django.core.cache.backends.locmem.LocMemCache"}}
    settings.API_THROTTLE_USER = "2/minute"
    client = APIClient()
    client.force_authenticate(owner)
    assert [client.get("/api/v1/runs/").status_code for _ in range(3)] == [200, 200, 429]


def test_refused_credentials_count_against_the_anonymous_rate(settings):
    settings.API_THROTTLE_ANON = "2/minute"
    address = "192.0.2.41"
    client = APIClient(REMOTE_ADDR=address, HTTP_AUTHORIZATION="Token guessed")
    assert [client.get("/api/v1/runs/").status_code for _ in range(2)] == [401, 401]
    refused = client.get("/api/v1/runs/")
    assert refused.status_code == 429
    assert int(refused["Retry-After"]) >= 1
    _is_envelope(refused.json(), "throttled")


def test_the_audit_log_is_for_admins_newest_first_and_filtered(client_for, admin_user, owner):
    for action in ("robot.stop", "reservation.create", "robot.stop"):
        audit_record(actor=owner, action=action, reason=action)
    page = client_for(admin_user).get("/api/v1/audit/?action=robot.stop").json()
    assert page["count"] == 2
    assert [e["action"] for e in page["results"]] == ["robot.stop", "robot.stop"]
    assert page["results"][0]["id"] > page["results"][1]["id"]
    assert page["results"][0]["actor"] == "alice"
    assert client_for(owner).get("/api/v1/audit/").status_code == 403


def test_me_says_who_the_token_belongs_to(api, client_for, admin_user):
    assert api.get("/api/v1/me/").json() == {
        "username": "alice",
        "email": "alice@example.org",
        "is_admin": False,
    }
    assert client_for(admin_user).get("/api/v1/me/").json()["is_admin"] is True


def test_a_reservation_is_cancelled_with_its_reason_in_the_query(api, owner, mobile):
    start = timezone.now() + timedelta(hours=2)
    booked = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=10),
        experiment=ExperimentFactory(owner=owner),
    )
    response = api.delete(f"/api/v1/reservations/{booked.pk}/?reason=rain")
    assert response.status_code == 200
    assert response.json()["cancel_reason"] == "rain"


def test_moving_only_the_end_keeps_the_start(api, owner, mobile):
    start = timezone.now() + timedelta(hours=2)
    booked = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=10),
        experiment=ExperimentFactory(owner=owner),
    )
    end = start + timedelta(minutes=20)
    response = api.patch(
        f"/api/v1/reservations/{booked.pk}/", {"end_at": end.isoformat()}, format="json"
    )
    assert response.status_code == 200, response.json()
    booked.refresh_from_db()
    assert (booked.start_at, booked.end_at) == (start, end)


@pytest.fixture
def schema(api) -> dict:
    response = api.get("/api/schema/", HTTP_ACCEPT="application/json")
    assert response.status_code == 200
    return response.json()


def _operations(schema: dict):
    for path, item in schema["paths"].items():
        for method, operation in item.items():
            yield path, method, operation


def test_the_schema_states_auth_throttling_and_errors_for_every_operation(schema):
    assert set(schema["components"]["securitySchemes"]) == {"tokenAuth"}
    operations = list(_operations(schema))
    assert len(operations) > 30
    envelope = {"$ref": "#/components/schemas/ErrorEnvelope"}
    for path, method, operation in operations:
        where = f"{method.upper()} {path}"
        # The one operation without a token: signing in for one (``amazing login``).
        signs_in = (method, path) == ("post", "/api/v1/auth/token/")
        expected = None if signs_in else [{"tokenAuth": []}]
        assert operation.get("security") == expected, where
        responses = operation["responses"]
        for code in ("401", "403", "429"):
            assert responses[code]["content"]["application/json"]["schema"] == envelope, where
        assert responses["401"]["headers"]["WWW-Authenticate"]["required"] is True
        assert responses["429"]["headers"]["Retry-After"]["required"] is True
        if "{" in path:
            assert "404" in responses, where
        if "requestBody" in operation:
            assert responses["413"]["content"]["application/json"]["schema"] == envelope, where
        if "requestBody" in operation or any(
            p["in"] == "query" for p in operation.get("parameters", [])
        ):
            assert "400" in responses, where


def test_the_schema_states_the_shapes_that_the_server_answers(schema):
    paths = schema["paths"]
    samples = paths["/api/v1/runs/{id}/samples/"]["get"]["responses"]["200"]
    ref = samples["content"]["application/json"]["schema"]["$ref"].rsplit("/", 1)[1]
    page = schema["components"]["schemas"][ref]
    assert {"run", "state", "samples", "last_seq"} <= set(page["required"])
    cancel = paths["/api/v1/reservations/{id}/"]["delete"]
    assert {"200", "409", "503"} <= set(cancel["responses"])
    assert [p["name"] for p in cancel["parameters"] if p["in"] == "query"] == ["reason"]
    create = paths["/api/v1/reservations/"]["post"]
    assert {"201", "400", "404", "409", "422", "503"} <= set(create["responses"])
    assert "X-Idempotency-Key" in [p["name"] for p in create["parameters"]]
    runs = paths["/api/v1/runs/"]["get"]
    assert {"limit", "offset", "state"} <= {p["name"] for p in runs["parameters"]}
    listing = runs["responses"]["200"]["content"]["application/json"]["schema"]["$ref"]
    assert listing.endswith("/PaginatedRunList")
    segment = schema["components"]["schemas"]["SegmentRequest"]
    assert segment["additionalProperties"] is False
    assert set(segment["required"]) == {"velocity_mps", "direction", "duration_s"}
    assert segment["properties"]["duration_s"]["exclusiveMinimum"] is True


def test_a_download_honours_accept_and_its_errors_stay_json(api, owner, mobile):
    from tests.runs.driving import completed_run

    run = completed_run(owner, mobile, [(0.5, "cw", 1.0)])
    csv_answer = api.get(f"/api/v1/runs/{run.pk}/samples.csv", HTTP_ACCEPT="text/csv")
    assert csv_answer.status_code == 200
    assert csv_answer["Content-Type"].startswith("text/csv")
    assert len(b"".join(csv_answer.streaming_content).splitlines()) == 21
    missing = api.get("/api/v1/runs/999999/samples.csv", HTTP_ACCEPT="text/csv")
    assert missing.status_code == 404
    assert missing["Content-Type"] == "application/json"
    _is_envelope(missing.json(), "not_found")


def test_a_name_that_is_a_slug_is_stated_as_one(schema, api):
    slug = "^[-a-zA-Z0-9_]+$"
    runs = {p["name"]: p for p in schema["paths"]["/api/v1/runs/"]["get"]["parameters"]}
    assert runs["resource"]["schema"]["pattern"] == slug
    booking = schema["components"]["schemas"]["ReservationRequest"]["properties"]
    assert booking["resources"]["items"]["pattern"] == slug
    # What the pattern refuses, the API refuses naming the field.
    refused = api.get("/api/v1/runs/?resource=mobile%201")
    assert refused.status_code == 400
    assert "resource" in refused.json()["fields"]
