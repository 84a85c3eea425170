"""A task waits in the queue once per subject (core/pending.py): a worker that has fallen behind
finds one staging per run, one pass per handlers' queue, not a copy per sweep or per commit;
what starts takes its note away, so the next change queues the next."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

import pytest
from django.core.cache import cache
from django.db import transaction
from django.utils import timezone

from core import pending
from core.events.services import event_record
from core.events.tasks import events_dispatch_all
from portal.queue.services import allocator_wake
from portal.queue.tasks import queue_allocate_task
from portal.runs import tasks
from portal.runs.models import Run
from portal.runs.services.reservations import reservation_create
from tests.factories import ExperimentFactory

pytestmark = pytest.mark.django_db


class Sent:
    """What ``apply_async`` was asked to send, per task, instead of sending it: a worker that
    has not taken anything yet."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, *task_objects: Any) -> None:
        self.calls: list[tuple[str, tuple[Any, ...], dict[str, Any]]] = []
        for task in task_objects:
            monkeypatch.setattr(task, "apply_async", self._recorder(task.name))

    def _recorder(self, name: str):
        def apply_async(args: Any = (), kwargs: Any = None, **options: Any) -> None:
            self.calls.append((name, tuple(args or ()), options))

        return apply_async

    def names(self) -> list[str]:
        return [name for name, _, _ in self.calls]


@pytest.fixture
def due_run(owner, mobile, settings):
    """A run starting in two minutes on a confirmed booking: due for staging at every sweep."""
    settings.RUN_STAGE_LEAD_S = 300
    start = timezone.now() + timedelta(minutes=2)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(seconds=10),
        experiment=ExperimentFactory(owner=owner),
    )
    return Run.objects.get(reservation=reservation)


def test_sweeps_behind_a_busy_worker_queue_one_staging_and_the_next_after_it_starts(
    monkeypatch, due_run
):
    sent = Sent(monkeypatch, tasks.run_stage)
    for _ in range(10):
        tasks.runs_sweep.apply()
    assert sent.calls == [
        ("portal.runs.tasks.run_stage", (due_run.pk,), {"expires": pending.PENDING_TTL_S})
    ]
    # The worker reaches it (it fails to stage here, no agent: what matters is the note).
    pending.pending_taken(f"portal.runs.tasks.run_stage:{due_run.pk}")
    tasks.runs_sweep.apply()
    assert sent.names() == ["portal.runs.tasks.run_stage"] * 2


def test_a_lost_task_is_queued_again_once_its_note_lapses(monkeypatch, due_run):
    sent = Sent(monkeypatch, tasks.run_stage)
    assert pending.queue_once(tasks.run_stage, "s", args=(due_run.pk,), ttl_s=1)
    assert not pending.queue_once(tasks.run_stage, "s", args=(due_run.pk,), ttl_s=1)
    cache.delete(pending._note("s"))  # lapsed, as after ttl_s with its task lost
    assert pending.queue_once(tasks.run_stage, "s", args=(due_run.pk,), ttl_s=1)
    assert len(sent.calls) == 2


def test_without_the_cache_a_task_is_queued_regardless(monkeypatch, caplog):
    sent = Sent(monkeypatch, queue_allocate_task)

    def down(*args: Any, **kwargs: Any) -> None:
        raise ConnectionError("cache down")

    monkeypatch.setattr(cache, "add", down)
    monkeypatch.setattr(cache, "delete", down)
    assert pending.queue_once(queue_allocate_task, "x")
    assert pending.queue_once(queue_allocate_task, "x")
    pending.pending_taken("x")  # logged, not raised
    assert len(sent.calls) == 2
    assert "the cache did not answer" in caplog.text


def test_a_send_that_fails_leaves_no_note(monkeypatch):
    def refused(*args: Any, **kwargs: Any) -> None:
        raise ConnectionError("broker down")

    monkeypatch.setattr(queue_allocate_task, "apply_async", refused)
    with pytest.raises(ConnectionError):
        pending.queue_once(queue_allocate_task, "y")
    sent = Sent(monkeypatch, queue_allocate_task)
    assert pending.queue_once(queue_allocate_task, "y")
    assert len(sent.calls) == 1


def test_twenty_commits_with_events_wake_each_handlers_queue_once_while_its_pass_waits(
    monkeypatch, owner, django_capture_on_commit_callbacks
):
    sent = Sent(monkeypatch, events_dispatch_all)

    def commit_an_event() -> None:
        with django_capture_on_commit_callbacks(execute=True), transaction.atomic():
            event_record(subject="run:1", type="run.running", payload={}, owner_id=owner.pk)

    for _ in range(20):
        commit_an_event()
    woken = [options.get("queue") for _, _, options in sent.calls]
    assert len(woken) == len(set(woken)) >= 1
    # A pass starts: the next commit wakes that queue again.
    queue = woken[0]
    events_dispatch_all.apply(kwargs={"queue": queue})
    commit_an_event()
    assert [options.get("queue") for _, _, options in sent.calls].count(queue) == 2


def test_a_campaigns_requests_and_a_resume_wake_the_allocator_once_while_it_waits(
    monkeypatch, django_capture_on_commit_callbacks
):
    sent = Sent(monkeypatch, queue_allocate_task)
    for _ in range(5):
        with django_capture_on_commit_callbacks(execute=True):
            allocator_wake()
    assert sent.names() == ["portal.queue.tasks.queue_allocate_task"]
