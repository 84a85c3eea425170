"""The ``eager_tasks`` fixture runs a task in-process only with what the broker can carry:
Celery's eager ``apply_async`` round-trips the arguments through the task's serializer."""

from __future__ import annotations

import pytest
from kombu.exceptions import EncodeError

from bookings.tasks import reservation_notify
from core.audit.models import TaskOnce
from tests.factories import UserFactory

pytestmark = pytest.mark.django_db


def test_a_task_given_a_model_instance_fails_as_it_would_on_the_broker(eager_tasks):
    with pytest.raises(EncodeError):
        reservation_notify.delay("confirmed", UserFactory())
    assert not TaskOnce.objects.exists()  # refused before it ran


def test_a_task_gets_its_arguments_as_a_worker_would(eager_tasks, monkeypatch):
    got: list[tuple[object, ...]] = []
    monkeypatch.setattr(
        "bookings.notifications.reservation_notify",
        lambda kind, reservation_id, **kwargs: got.append((kind, reservation_id, kwargs)),
    )
    reservation_notify.delay("confirmed", 7, via="the API")
    assert got == [("confirmed", 7, {"blackout_id": None, "via": "the API"})]
