"""``manage.py demo_setup``: a start without the second robot takes it out of booking, a start
with it puts it back."""

from __future__ import annotations

import io
from datetime import timedelta

import pytest
from django.core.management import call_command
from django.test import Client
from django.utils import timezone

from bookings.management.commands.demo_setup import RSSI_TOKEN_NAME
from bookings.models import Resource
from bookings.services import reservation_create, resource_hold
from core.accounts.models import ApiToken, User
from core.audit.models import AuditEvent
from core.errors import InvalidInput
from core.fleet import SECOND_ROBOT

pytestmark = pytest.mark.django_db

SECOND_AGENT = "http://127.0.0.1:8701"
REASON = "agent not configured: started without it (ROBOTS=2 runs its agent)"


def _setup(*args: str) -> str:
    out = io.StringIO()
    call_command("demo_setup", *args, stdout=out)
    return out.getvalue()


def _second() -> Resource:
    return Resource.objects.get(name=SECOND_ROBOT)


def _book(owner, robot: Resource):
    start = timezone.now() + timedelta(hours=2)
    return reservation_create(
        owner=owner,
        resource=robot,
        start_at=start,
        end_at=start + timedelta(minutes=10),
        program_required=False,
    )


def test_a_start_without_the_second_robot_takes_it_out_and_one_with_it_puts_it_back(owner):
    _setup("--second-robot", SECOND_AGENT)
    assert _second().in_service
    assert _second().agent_token_name == SECOND_ROBOT

    out = _setup()
    assert f"{SECOND_ROBOT} out of booking" in out
    assert _second().hold_reason == REASON
    with pytest.raises(InvalidInput) as refused:
        _book(owner, _second())
    assert refused.value.message == f"{SECOND_ROBOT} is out of service: {REASON}."
    assert Resource.objects.get(name="mobile-1").in_service
    _setup()  # again: still out, held once
    assert AuditEvent.objects.filter(action="resource.hold").count() == 1

    out = _setup("--second-robot", SECOND_AGENT)
    assert f"{SECOND_ROBOT} back in booking" in out
    assert _second().in_service
    [lifted] = AuditEvent.objects.filter(action="resource.hold_lifted")
    assert lifted.actor_name == "system"
    assert lifted.data == {"lifted_hold": REASON}
    _book(owner, _second())


def test_a_start_with_the_second_robot_leaves_a_hold_of_another_cause_to_an_admin():
    _setup("--second-robot", SECOND_AGENT)
    resource_hold(resource_id=_second().pk, reason="emergency stop latched: rail blocked")
    _setup("--second-robot", SECOND_AGENT)
    assert _second().hold_reason == "emergency stop latched: rail blocked"


def test_a_first_start_without_the_second_robot_makes_none():
    _setup()
    assert not Resource.objects.filter(name=SECOND_ROBOT).exists()


def test_the_demo_signal_strengths_token_is_new_at_each_start_and_only_its_files(tmp_path):
    path = tmp_path / "demo-rssi-token"
    _setup("--rssi-token-file", str(path))
    first = path.read_text().strip()
    _setup("--rssi-token-file", str(path))
    second = path.read_text().strip()
    assert first != second
    assert path.stat().st_mode & 0o777 == 0o600
    experimenter = User.objects.get(username="experimenter")
    tokens = ApiToken.objects.filter(user=experimenter, name=RSSI_TOKEN_NAME)
    assert tokens.count() == 1  # the first start's is revoked
    me = [
        Client().get("/api/v1/me/", HTTP_AUTHORIZATION=f"Token {token}")
        for token in (first, second)
    ]
    assert [answer.status_code for answer in me] == [401, 200]
    assert me[1].json()["username"] == "experimenter"
