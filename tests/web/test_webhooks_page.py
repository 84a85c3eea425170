"""The webhooks pages: make one (its secret shown once, never cached), its delivery log, a test
event, a resume, a delete after a confirmation; each only to its owner, each through the same
service as the API (its audit record)."""

from __future__ import annotations

from typing import Any

import pytest
from django.test import Client
from django.utils import timezone

from core.audit.models import AuditEvent
from core.events.dispatch import events_dispatch
from core.events.sequence import events_sequence
from core.webhooks import services
from core.webhooks.models import WebhookDelivery, WebhookSubscription
from tests.conftest import sign_in_with_second_factor
from tests.factories import UserFactory

pytestmark = pytest.mark.django_db

HOOK = "http://127.0.0.1:9/hook"


@pytest.fixture
def alice(owner: Any) -> Client:
    client = Client()
    client.force_login(owner)
    return client


def test_a_webhook_made_on_the_page_shows_its_secret_once_and_is_listed(alice, owner):
    answer = alice.post(
        "/account/webhooks/",
        {"url": HOOK, "description": "lab bot", "types": ["run.completed", "run.failed"]},
    )
    assert answer.status_code == 200
    assert answer["Cache-Control"].startswith("no-store")
    subscription = WebhookSubscription.objects.get(owner=owner)
    assert (subscription.url, subscription.description) == (HOOK, "lab bot")
    assert subscription.types == ["run.completed", "run.failed"]
    assert not subscription.staff_events
    page = answer.content.decode()
    assert 'data-testid="new-webhook-secret"' in page
    secret = page.split('data-testid="new-webhook-secret"')[0].rsplit('value="', 1)[1]
    assert secret.startswith("whsec_")
    # Listed, and the secret never again.
    again = alice.get("/account/webhooks/").content.decode()
    assert HOOK in again
    assert "run.completed, run.failed" in again
    assert secret.split('"')[0] not in again
    assert AuditEvent.objects.filter(action="webhook.create", actor=owner).count() == 1


def test_the_form_refuses_a_bad_url_and_makes_nothing(alice, owner, settings):
    settings.WEBHOOK_ALLOW_HTTP = False
    answer = alice.post("/account/webhooks/", {"url": HOOK})
    assert answer.status_code == 200
    assert "https" in answer.content.decode()
    assert not WebhookSubscription.objects.exists()
    assert alice.post("/account/webhooks/", {"url": "not a url"}).status_code == 200
    assert not WebhookSubscription.objects.exists()


def test_staffs_events_are_offered_to_staff_with_the_second_factor_only(owner):
    staff = UserFactory(username="sam", is_staff=True, is_superuser=True)
    password_only = Client()
    password_only.force_login(staff)
    assert "staff_events" not in password_only.get("/account/webhooks/").content.decode()
    # Posted anyway: the field is not the form's, so a plain webhook is made.
    password_only.post("/account/webhooks/", {"url": HOOK, "staff_events": "on"})
    assert WebhookSubscription.objects.get(owner=staff).staff_events is False
    # Nor can a plain webhook ask for the robots' events.
    password_only.post("/account/webhooks/", {"url": HOOK, "types": ["robot.held"]})
    assert WebhookSubscription.objects.filter(owner=staff).count() == 1

    verified = sign_in_with_second_factor(Client(), staff)
    assert "staff_events" in verified.get("/account/webhooks/").content.decode()
    verified.post(
        "/account/webhooks/", {"url": HOOK, "staff_events": "on", "types": ["robot.held"]}
    )
    made = WebhookSubscription.objects.filter(owner=staff).latest("pk")
    assert (made.staff_events, made.types) == (True, ["robot.held"])


def test_a_test_event_shows_in_the_log_and_a_paused_webhook_is_resumed_there(alice, owner):
    subscription, _ = services.webhook_create(owner=owner, url=HOOK)
    answer = alice.post(f"/account/webhooks/{subscription.pk}/test/")
    assert answer.status_code == 302
    events_sequence()
    events_dispatch(name="webhooks")
    delivery = WebhookDelivery.objects.get(subscription=subscription)
    assert delivery.event.type == "webhook.test"
    log = alice.get(f"/account/webhooks/{subscription.pk}/").content.decode()
    assert "webhook.test" in log
    assert "pending" in log
    assert 'data-testid="webhook-resume"' not in log

    WebhookSubscription.objects.filter(pk=subscription.pk).update(
        paused_at=timezone.now(), pause_reason="event 1 (webhook.test): no answer"
    )
    WebhookDelivery.objects.filter(pk=delivery.pk).update(state="failed")
    log = alice.get(f"/account/webhooks/{subscription.pk}/").content.decode()
    assert "Paused" in log
    assert "no answer" in log
    assert "failed" in log
    alice.post(f"/account/webhooks/{subscription.pk}/resume/")
    subscription.refresh_from_db()
    delivery.refresh_from_db()
    assert (subscription.paused_at, delivery.state) == (None, "pending")
    assert AuditEvent.objects.filter(action="webhook.resume", actor=owner).exists()


def test_delete_asks_first_then_deletes(alice, owner):
    subscription, _ = services.webhook_create(owner=owner, url=HOOK)
    confirm = alice.get(f"/account/webhooks/{subscription.pk}/delete/")
    assert confirm.status_code == 200
    assert "Delete this webhook?" in confirm.content.decode()
    assert WebhookSubscription.objects.filter(pk=subscription.pk).exists()
    answer = alice.post(f"/account/webhooks/{subscription.pk}/delete/")
    assert (answer.status_code, answer["Location"]) == (302, "/account/webhooks/")
    assert not WebhookSubscription.objects.filter(pk=subscription.pk).exists()
    assert AuditEvent.objects.filter(action="webhook.delete", actor=owner).exists()


def test_another_users_webhook_is_not_found_on_any_of_its_pages(owner, other):
    subscription, _ = services.webhook_create(owner=owner, url=HOOK)
    bob = Client()
    bob.force_login(other)
    for method, path in (
        ("get", ""),
        ("post", "test/"),
        ("post", "resume/"),
        ("get", "delete/"),
        ("post", "delete/"),
    ):
        answer = getattr(bob, method)(f"/account/webhooks/{subscription.pk}/{path}")
        assert answer.status_code == 404, (method, path)
    assert WebhookSubscription.objects.filter(pk=subscription.pk).exists()
    assert not AuditEvent.objects.filter(actor=other, action__startswith="webhook.").exists()
    assert HOOK not in bob.get("/account/webhooks/").content.decode()
