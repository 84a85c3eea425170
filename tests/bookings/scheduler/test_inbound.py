"""The robot booked in the testbed scheduler's own lease vocabulary.

The client is a script run in its own process that knows only HTTP and the broker's
vocabulary: no portal import, no Django.
"""

from __future__ import annotations

import json
import subprocess
import sys
from datetime import timedelta
from pathlib import Path

import pytest
from django.contrib.auth.models import Permission
from django.utils import timezone

from bookings.choices import BookedVia
from bookings.models import Blackout, QuotaPolicy, Reservation
from bookings.services import reservations as without_run
from portal.runs.services.reservations import reservation_create
from tests.factories import ExperimentFactory, FixedResourceFactory, UserFactory, api_token

pytestmark = pytest.mark.django_db(transaction=True)

CLIENT = r"""
import json, sys
import requests

base, token, command = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
headers = {"Accept": "application/json"}
if token:
    headers["Authorization"] = f"Token {token}"
response = requests.request(
    command["method"], base + command["path"], json=command.get("body"), headers=headers,
    timeout=10,
)
print(json.dumps({"status": response.status_code, "body": response.json()}))
"""


@pytest.fixture
def broker_client(live_server, tmp_path):
    script = tmp_path / "lease_client.py"
    script.write_text(CLIENT)

    def call(method: str, path: str, body: dict | None = None, token: str | None = None):
        result = subprocess.run(
            [sys.executable, str(script), f"{live_server.url}/scheduler", token or "",
             json.dumps({"method": method, "path": path, "body": body})],
            capture_output=True, text=True, timeout=60, cwd=Path(script).parent,
        )  # fmt: skip
        assert result.returncode == 0, result.stderr
        return json.loads(result.stdout)

    return call


@pytest.fixture
def service_token() -> str:
    account = UserFactory(username="testbed-scheduler")
    account.user_permissions.add(Permission.objects.get(codename="lease_inbound"))
    return api_token(account)


@pytest.fixture
def lease_body(mobile, owner):
    start = (timezone.now() + timedelta(days=1)).replace(microsecond=0)

    def body(minutes: int = 30, offset_min: int = 0) -> dict:
        begin = start + timedelta(minutes=offset_min)
        return {
            "name": "r2lab-robot-session",
            "valid_from": begin.strftime("%Y-%m-%dT%H:%M:%SZ"),
            "valid_until": (begin + timedelta(minutes=minutes)).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "account_attributes": {"name": owner.username},
            "components": [{"name": mobile.name}],
        }

    return body


def test_it_lists_the_robot_as_a_node(broker_client, service_token, mobile):
    FixedResourceFactory(name="node-01")  # fixed nodes are the scheduler's own, not listed here
    answer = broker_client("GET", "/resources/nodes", token=service_token)
    assert answer["status"] == 200
    [node] = answer["body"]["resource_response"]["resources"]
    assert (node["name"], node["urn"], node["resource_type"]) == (
        "mobile-1",
        "urn:publicid:IDN+amazing+node+mobile-1",
        "node",
    )


def test_a_lease_on_the_robot_books_it_for_the_account_and_is_listed(
    broker_client, service_token, lease_body, owner
):
    answer = broker_client("POST", "/resources/leases", lease_body(), token=service_token)
    assert answer["status"] == 200, answer
    lease = answer["body"]["resource_response"]["resource"]
    assert lease["status"] == "accepted"
    assert lease["account"]["name"] == owner.username
    assert [c["name"] for c in lease["components"]] == ["mobile-1"]
    reservation = Reservation.objects.get(public_id=lease["uuid"])
    assert reservation.owner == owner
    assert reservation.booked_via == BookedVia.SCHEDULER
    listed = broker_client("GET", "/resources/leases", token=service_token)
    assert [x["uuid"] for x in listed["body"]["resource_response"]["resources"]] == [lease["uuid"]]
    moved = broker_client(
        "PUT",
        "/resources/leases",
        {
            "uuid": lease["uuid"],
            **{k: lease_body(offset_min=60)[k] for k in ("valid_from", "valid_until")},
        },
        token=service_token,
    )
    assert moved["status"] == 200, moved
    assert (
        moved["body"]["resource_response"]["resource"]["valid_from"]
        == lease_body(offset_min=60)["valid_from"]
    )
    gone = broker_client(
        "DELETE", "/resources/leases", {"uuid": lease["uuid"]}, token=service_token
    )
    assert gone["body"]["resource_response"]["resource"]["status"] == "cancelled"


def test_refusals_come_back_in_the_brokers_envelope(
    broker_client, service_token, lease_body, owner, mobile
):
    without_run.reservation_create(
        owner=UserFactory(username="zed"),
        resource=mobile,
        start_at=timezone.now() + timedelta(days=1, hours=-1),
        end_at=timezone.now() + timedelta(days=1, minutes=10),
        program_required=False,
    )
    overlap = broker_client("POST", "/resources/leases", lease_body(), token=service_token)
    assert overlap["status"] == 409
    assert overlap["body"]["exception"]["code"] == 409
    assert overlap["body"]["exception"]["reason"].startswith(
        "Reservation for the resource 'mobile-1' failed: mobile-1 is already booked"
    )
    later = lease_body(offset_min=120)
    Blackout.objects.create(
        start_at=timezone.now() + timedelta(days=1, hours=2),
        end_at=timezone.now() + timedelta(days=1, hours=3),
        reason="rail inspection",
        all_resources=True,
    )
    blackout = broker_client("POST", "/resources/leases", later, token=service_token)
    assert blackout["status"] == 409
    assert "Maintenance “rail inspection”" in blackout["body"]["exception"]["reason"]
    QuotaPolicy.objects.create(name="short", max_length_s=600)
    quota = broker_client(
        "POST", "/resources/leases", lease_body(offset_min=300), token=service_token
    )
    assert quota["status"] == 403
    assert quota["body"]["exception"]["reason"].startswith("Quota: “short” allows")
    assert not Reservation.objects.filter(booked_via=BookedVia.SCHEDULER).exists()


def test_without_the_service_account_nothing_is_answered_but_the_envelope(
    broker_client, lease_body, owner
):
    anonymous = broker_client("POST", "/resources/leases", lease_body())
    assert anonymous == {
        "status": 401,
        "body": {"exception": {"code": 401, "reason": "Missing or invalid credentials."}},
    }
    token = api_token(owner)
    plain_user = broker_client("GET", "/resources/leases", token=token)
    assert plain_user["status"] == 403
    assert not Reservation.objects.exists()


def test_bad_leases_are_refused_clearly(broker_client, service_token, lease_body):
    unknown = {**lease_body(), "components": [{"name": "node-07"}]}
    answer = broker_client("POST", "/resources/leases", unknown, token=service_token)
    assert answer["status"] == 404
    assert "this portal leases mobile-1" in answer["body"]["exception"]["reason"]
    nobody = {**lease_body(), "account_attributes": {"name": "nobody"}}
    assert broker_client("POST", "/resources/leases", nobody, token=service_token)["status"] == 404
    naive = {**lease_body(), "valid_from": "2030-01-01T10:00:00"}
    assert broker_client("POST", "/resources/leases", naive, token=service_token)["status"] == 400
    assert broker_client("POST", "/resources/leases", [1, 2], token=service_token)["status"] == 400
    assert not Reservation.objects.exists()


def test_a_booking_made_in_the_portal_is_listed_but_not_changed_through_leases(
    broker_client, service_token, owner, mobile
):
    start = timezone.now() + timedelta(days=2)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=20),
        experiment=ExperimentFactory(owner=owner),
    )
    listed = broker_client("GET", "/resources/leases", token=service_token)
    [lease] = listed["body"]["resource_response"]["resources"]
    assert lease["uuid"] == str(reservation.public_id)
    refused = broker_client(
        "DELETE", "/resources/leases", {"uuid": lease["uuid"]}, token=service_token
    )
    assert refused["status"] == 403
    reservation.refresh_from_db()
    assert reservation.is_active
