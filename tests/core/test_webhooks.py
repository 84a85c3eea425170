"""Webhooks: a user's events sent to their URL, signed (Standard Webhooks), retried with the same
id until accepted, in order, paused after the retry window; and sent only where the guard
allows. The receiver is a process of its own on loopback (``tests/core/webhook_receiver.py``),
which verifies each signature with ``standardwebhooks``."""

from __future__ import annotations

import time
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest
from django.core import mail
from django.utils import timezone

from bookings.services import resource_hold
from core.errors import InvalidInput, NotAllowed
from core.events.dispatch import events_dispatch
from core.events.models import Event, EventCursor
from core.events.registry import handled
from core.events.sequence import events_sequence
from core.webhooks import delivery, services
from core.webhooks.guard import Refused, webhook_target
from core.webhooks.models import WebhookDelivery, WebhookSubscription
from portal.runs.models import Run
from portal.runs.services.reservations import reservation_create
from portal.runs.services.transitions import run_transition
from portal.runs.states import Cause, RunState
from tests.core.webhook_receiver import Receiver
from tests.factories import ExperimentFactory, FixedResourceFactory, MobileResourceFactory

pytestmark = pytest.mark.django_db

DEADLINE_S = 30.0  # bounds a hang only


@pytest.fixture
def receivers(tmp_path: Path) -> Iterator[Any]:
    started: list[Receiver] = []

    def make(secret: str, **env: str) -> Receiver:
        directory = tmp_path / f"receiver-{len(started)}"
        directory.mkdir()
        receiver = Receiver(directory, secret, **env)
        receiver.start()
        started.append(receiver)
        return receiver

    yield make
    for receiver in started:
        receiver.stop()


@pytest.fixture(autouse=True)
def quick_retries(settings: Any) -> None:
    settings.WEBHOOK_RETRY_FIRST_S = 0.2
    settings.WEBHOOK_RETRY_MAX_S = 0.5


def _subscribed(owner: Any, url: str = "http://127.0.0.1:9/hook", **options: Any) -> Any:
    return services.webhook_create(owner=owner, url=url, **options)


def _fan_out() -> None:
    """What the mail worker's pass does: the events made into deliveries."""
    events_sequence()
    events_dispatch(name="webhooks")


def _send_until_settled() -> None:
    """Send passes, as the worker's task does, until nothing is pending (or the deadline)."""
    deadline = time.monotonic() + DEADLINE_S
    while WebhookDelivery.objects.filter(state=WebhookDelivery.State.PENDING).exists():
        assert time.monotonic() < deadline, list(WebhookDelivery.objects.values())
        _, next_pass_s = delivery.webhook_deliveries_send()
        time.sleep(min(next_pass_s or 0.05, 0.5))


def _a_run_that_completed(owner: Any, mobile: Any) -> Run:
    start = timezone.now() + timedelta(hours=2)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=10),
        experiment=ExperimentFactory(owner=owner),
    )
    run = Run.objects.get(reservation=reservation)
    for state in (RunState.STAGED, RunState.RUNNING, RunState.COLLECTING, RunState.COMPLETED):
        assert run_transition(run_id=run.pk, to_state=state, cause=Cause.DISPATCH)
    return run


def test_a_booked_runs_events_reach_the_receiver_signed_in_order_and_retried_with_one_id(
    owner, other, mobile, receivers
):
    subscription, secret = _subscribed(owner)
    receiver = receivers(secret, FAIL_FIRST="2")
    services.webhook_update(subscription=subscription, by=owner, url=receiver.url)
    _subscribed(other)  # someone else's webhook: never sent alice's events
    _a_run_that_completed(owner, mobile)
    _fan_out()
    _send_until_settled()

    mine = list(Event.objects.filter(owner=owner).order_by("position"))
    assert [e.type for e in mine] == [
        "reservation.created",
        "run.scheduled",
        "run.staged",
        "run.running",
        "run.collecting",
        "run.completed",
    ]
    got = receiver.received()
    assert all(line["verified"] for line in got), got
    # Two 500s, then the same event again with the same id, accepted; then each once, in order.
    assert [line["answer"] for line in got[:3]] == [500, 500, 200]
    assert len({line["webhook_id"] for line in got[:3]}) == 1
    accepted = [line for line in got if line["answer"] == 200]
    assert [line["id"] for line in accepted] == [e.position for e in mine]
    assert [line["webhook_id"] for line in accepted] == [f"evt_{e.position}" for e in mine]
    first = WebhookDelivery.objects.get(subscription=subscription, event=mine[0])
    assert (first.state, first.attempts, first.last_status) == ("delivered", 3, 200)
    assert not WebhookDelivery.objects.exclude(subscription=subscription).exists()


def test_a_receiver_down_for_a_while_gets_every_event_once_it_is_back(owner, mobile, receivers):
    subscription, secret = _subscribed(owner)
    receiver = receivers(secret)
    services.webhook_update(subscription=subscription, by=owner, url=receiver.url)
    receiver.stop()
    _a_run_that_completed(owner, mobile)
    _fan_out()
    for _ in range(3):
        delivery.webhook_deliveries_send()
        time.sleep(0.25)
    waiting = WebhookDelivery.objects.order_by("event__position").first()
    assert waiting is not None
    assert waiting.state == "pending"
    assert waiting.attempts >= 2
    assert waiting.last_status is None
    assert waiting.last_error.startswith("no answer")
    # Later ones wait behind it: the order holds.
    assert WebhookDelivery.objects.filter(attempts__gt=0).count() == 1
    receiver.start()  # back, on its port
    _send_until_settled()
    ids = [line["id"] for line in receiver.received()]
    assert ids == sorted(Event.objects.filter(owner=owner).values_list("position", flat=True))


def test_a_webhook_failing_for_its_whole_window_is_paused_and_its_owner_told(
    owner, receivers, settings, eager_tasks, django_capture_on_commit_callbacks
):
    settings.WEBHOOK_RETRY_FOR_S = 1.0
    subscription, secret = _subscribed(owner)
    receiver = receivers(secret, FAIL_FIRST="1000")
    services.webhook_update(subscription=subscription, by=owner, url=receiver.url)
    tried = services.webhook_test(subscription=subscription, by=owner)
    _fan_out()
    with django_capture_on_commit_callbacks(execute=True):
        _send_until_settled()
    subscription.refresh_from_db()
    assert subscription.paused_at is not None
    assert f"event {tried.position} (webhook.test)" in subscription.pause_reason
    failed = WebhookDelivery.objects.get(event=tried)
    assert (failed.state, failed.last_status) == ("failed", 500)
    # Told by e-mail, through the pause's own event.
    events_sequence()
    events_dispatch(name="webhook-paused-mail")
    assert [m.subject for m in mail.outbox] == [f"Webhook paused: {receiver.url}"]
    # Nothing is sent while paused; resumed, the failed one goes again.
    count = len(receiver.received())
    delivery.webhook_deliveries_send()
    assert len(receiver.received()) == count
    services.webhook_resume(subscription=subscription, by=owner)
    assert WebhookDelivery.objects.get(event=tried).state == "pending"


def test_a_redirect_is_not_followed(owner, receivers):
    target = receivers("whsec_" + "A" * 32)
    subscription, secret = _subscribed(owner)
    redirecting = receivers(secret, REDIRECT=target.url)
    services.webhook_update(subscription=subscription, by=owner, url=redirecting.url)
    tried = services.webhook_test(subscription=subscription, by=owner)
    _fan_out()
    delivery.webhook_deliveries_send()
    attempt = WebhookDelivery.objects.get(event=tried)
    assert (attempt.last_status, attempt.last_error) == (302, "a redirect: not followed")
    assert target.received() == []


@pytest.mark.parametrize(
    "url",
    [
        "http://93.184.216.34/hook",  # not https
        "https://10.0.0.7/hook",  # private IPv4
        "https://127.0.0.1/hook",  # loopback IPv4
        "https://169.254.169.254/latest/meta-data",  # link-local: the metadata service
        "https://[::1]/hook",  # loopback IPv6
        "https://[fd00::1]/hook",  # private IPv6
        "https://[::ffff:127.0.0.1]/hook",  # IPv4 loopback inside IPv6
        "https://localhost/hook",  # a name that resolves to 127.0.0.1
        "https://user:secret@93.184.216.34/hook",  # credentials in the URL
    ],
)
def test_production_refuses_what_is_not_a_public_https_url(owner, settings, url):
    settings.WEBHOOK_ALLOW_HTTP = False
    settings.WEBHOOK_ALLOW_PRIVATE = False
    with pytest.raises(Refused):
        webhook_target(url)
    with pytest.raises(InvalidInput) as refused:
        _subscribed(owner, url=url)
    assert "url" in refused.value.fields
    assert not WebhookSubscription.objects.exists()


def test_production_sends_to_a_public_address_as_checked(settings):
    settings.WEBHOOK_ALLOW_HTTP = False
    settings.WEBHOOK_ALLOW_PRIVATE = False
    target = webhook_target("https://93.184.216.34:8443/hook?x=1")
    assert (target.address, target.port, target.path) == ("93.184.216.34", 8443, "/hook?x=1")


def test_the_guard_is_asked_again_at_each_try(owner, receivers, settings):
    subscription, secret = _subscribed(owner)
    receiver = receivers(secret)
    services.webhook_update(subscription=subscription, by=owner, url=receiver.url)
    tried = services.webhook_test(subscription=subscription, by=owner)
    _fan_out()
    settings.WEBHOOK_ALLOW_PRIVATE = False  # as if its name now resolved to this machine
    delivery.webhook_deliveries_send()
    attempt = WebhookDelivery.objects.get(event=tried)
    assert attempt.last_error.startswith("refused: 127.0.0.1 is not a public address")
    assert receiver.received() == []


def test_staff_events_are_for_staff_only_and_a_type_filter_holds(owner, admin_user):
    with pytest.raises(NotAllowed):
        _subscribed(owner, staff_events=True)
    with pytest.raises(InvalidInput):
        _subscribed(owner, types=["robot.held"])
    with pytest.raises(InvalidInput):
        _subscribed(owner, types=["run.teleported"])
    runs_only, _ = _subscribed(owner, types=["run.completed"])
    staff, _ = _subscribed(admin_user, staff_events=True, types=["robot.held"])
    mobile_start = timezone.now() + timedelta(hours=2)
    assert runs_only.types == ["run.completed"]
    robot = MobileResourceFactory()
    assert resource_hold(resource_id=robot.pk, reason="battery low")
    reservation_create(
        owner=owner,
        resource=FixedResourceFactory(),
        start_at=mobile_start,
        end_at=mobile_start + timedelta(minutes=5),
    )
    _fan_out()
    assert list(WebhookDelivery.objects.values_list("subscription_id", "event__type")) == [
        (staff.pk, "robot.held")
    ]


def test_the_api_shows_the_secret_once_and_each_webhook_only_to_its_owner(
    owner, other, client_for, receivers
):
    api = client_for(owner)
    made = api.post(
        "/api/v1/webhooks/",
        {"url": "http://127.0.0.1:9/hook", "types": ["run.completed"]},
        format="json",
    )
    assert made.status_code == 201, made.content
    body = made.json()
    assert body["secret"].startswith("whsec_")
    assert body["types"] == ["run.completed"]
    pk = body["id"]
    shown = api.get(f"/api/v1/webhooks/{pk}/").json()
    assert "secret" not in shown
    assert client_for(other).get(f"/api/v1/webhooks/{pk}/").status_code == 404
    assert client_for(other).post(f"/api/v1/webhooks/{pk}/test/").status_code == 404
    refused = api.post("/api/v1/webhooks/", {"url": "ftp://example.org/"}, format="json")
    assert refused.status_code == 400
    receiver = receivers(body["secret"])
    changed = api.patch(f"/api/v1/webhooks/{pk}/", {"url": receiver.url}, format="json")
    assert changed.status_code == 200, changed.content
    sent = api.post(f"/api/v1/webhooks/{pk}/test/")
    assert sent.status_code == 202
    _fan_out()
    delivery.webhook_deliveries_send()
    log = api.get(f"/api/v1/webhooks/{pk}/deliveries/").json()["results"]
    assert [(d["type"], d["state"], d["last_status"]) for d in log] == [
        ("webhook.test", "delivered", 200)
    ]
    assert log[0]["webhook_id"] == f"evt_{sent.json()['event']}"
    assert [line["verified"] for line in receiver.received()] == [True]
    assert api.delete(f"/api/v1/webhooks/{pk}/").status_code == 204
    assert not WebhookSubscription.objects.exists()


def test_without_a_webhook_events_wake_no_one_and_are_passed_over(owner, mobile):
    """Most deployments have no webhook: their events must cost nothing more (a run's data
    ready, which no other handler takes, wakes no one)."""
    assert not handled("run.data_ready")
    _a_run_that_completed(owner, mobile)
    events_sequence()
    assert events_dispatch(name="webhooks") == 0
    top = Event.objects.order_by("-position").values_list("position", flat=True).first()
    assert EventCursor.objects.get(handler="webhooks").position == top
    _subscribed(owner)
    assert handled("run.data_ready")
    assert not WebhookDelivery.objects.exists()  # the events before it are not its
