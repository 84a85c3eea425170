"""The ``eager_tasks`` fixture runs a task in-process only with what the broker can carry:
Celery's eager ``apply_async`` round-trips the arguments through the task's serializer."""

from __future__ import annotations

import pytest
from kombu.exceptions import EncodeError

from bookings.tasks import lease_cancel
from tests.factories import UserFactory

pytestmark = pytest.mark.django_db


def test_a_task_given_a_model_instance_fails_as_it_would_on_the_broker(eager_tasks, monkeypatch):
    called: list[object] = []
    monkeypatch.setattr("bookings.leases.lease_release", lambda **kwargs: called.append(kwargs))
    with pytest.raises(EncodeError):
        lease_cancel.delay(UserFactory())
    assert called == []  # refused before it ran


def test_a_task_gets_its_arguments_as_a_worker_would(eager_tasks, monkeypatch):
    got: list[dict[str, object]] = []
    monkeypatch.setattr("bookings.leases.lease_release", lambda **kwargs: got.append(kwargs))
    lease_cancel.delay("b6f0c1d2-0000-4000-8000-000000000001")
    assert got == [{"lease_uuid": "b6f0c1d2-0000-4000-8000-000000000001"}]
