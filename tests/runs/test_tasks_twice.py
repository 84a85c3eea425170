"""Every Celery task is safe to run twice: what a redelivered message does again changes
nothing (no second sample, state change, hold, audit entry or e-mail).

Celery delivers a message again, with the same task id, when its worker died before
acknowledging it (``acks_late``); the sweeps also queue whatever is still due. Each test
here runs one task twice with the same id and compares the effects with one run. A test at
the end checks that every task the workers know is covered.
"""

from __future__ import annotations

import uuid
from datetime import UTC, datetime, time, timedelta

import pytest
import time_machine
from django.core import mail
from django.utils import timezone

from bookings.models import Reservation
from bookings.services import resource_hold
from bookings.tasks import reservations_remind
from core.audit.models import AuditEvent, IdempotencyKey
from core.audit.tasks import idempotency_keys_delete_expired
from core.events.dispatch import events_dispatch
from core.events.models import Event, EventCursor
from core.events.tasks import events_dispatch_all
from core.webhooks.models import WebhookDelivery
from core.webhooks.services import webhook_create, webhook_test, webhook_update
from core.webhooks.tasks import webhooks_send
from portal.celery import app as celery_app
from portal.runs import tasks
from portal.runs.models import DryRun, Run, RunEvent, Sample, SelfCheck
from portal.runs.services import dry_run, staging
from portal.runs.services.reservations import reservation_cancel, reservation_create
from portal.runs.services.self_check import self_check_schedule_set
from portal.runs.states import RunState
from tests.core.test_webhooks import Receiver
from tests.factories import ExperimentFactory, FixedResourceFactory, UserFactory

pytestmark = pytest.mark.django_db

# Each is run twice by a test below; a new task is added here with its test.
COVERED = {
    "portal.runs.tasks.runs_sweep",
    "portal.runs.tasks.run_stage",
    "portal.runs.tasks.run_unstage",
    "portal.runs.tasks.run_hold",
    "portal.runs.tasks.run_collect",
    "portal.runs.tasks.robots_health_sweep",
    "portal.runs.tasks.robot_health_check",
    "portal.runs.tasks.dry_run_execute",
    "portal.runs.tasks.dry_runs_delete_expired",
    "portal.runs.tasks.self_checks_book_scheduled",
    "bookings.tasks.reservations_remind",
    "core.audit.tasks.idempotency_keys_delete_expired",
    "core.events.tasks.events_dispatch_all",
    "core.webhooks.tasks.webhooks_send",
    "portal.queue.tasks.queue_allocate_task",
    # Run twice in tests/bookings/scheduler/test_booking_flow.py (they need the stand-in).
    "bookings.tasks.scheduler_sweep",
    "bookings.tasks.lease_cancel",
}


def twice(task, *args) -> None:
    """Run ``task`` as the same message delivered twice."""
    assert task.name in COVERED
    task_id = str(uuid.uuid4())
    for _ in range(2):
        result = task.apply(args=args, task_id=task_id)
        assert result.successful(), result.traceback


@pytest.fixture
def run(agent, owner, mobile) -> Run:
    mobile.agent_url = agent.url
    mobile.save()
    start = timezone.now() + timedelta(minutes=2)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(seconds=10),
        experiment=ExperimentFactory(
            owner=owner, segments=[{"velocity_mps": 0.5, "direction": "cw", "duration_s": 2.0}]
        ),
    )
    events_dispatch_all.apply()  # the booking's own e-mail, out of the tests' way
    mail.outbox.clear()
    return Run.objects.get(reservation=reservation)


def _events(run: Run) -> list[str]:
    return list(RunEvent.objects.filter(run=run).values_list("to_state", flat=True))


def test_staging_twice_stages_once(agent, run):
    twice(tasks.run_stage, run.pk)
    assert _events(run) == ["scheduled", "staged"]
    assert [r["id"] for r in agent.client.list_runs()] == [run.agent_run_id]


def test_withdrawing_twice_withdraws_once(agent, run, owner):
    staging.run_stage(run_id=run.pk)
    reservation_cancel(reservation=run.reservation, by=owner)
    twice(tasks.run_unstage, run.pk)
    assert _events(run) == ["scheduled", "staged", "cancelled"]
    assert agent.client.get_run(run.agent_run_id)["state"] == "cancelled"


def test_holding_twice_holds_once(agent, run):
    # Its booking moved without it (a write around the booking services).
    Reservation.objects.filter(pk=run.reservation_id).update(
        start_at=run.start_at + timedelta(hours=3), end_at=run.end_at + timedelta(hours=3)
    )
    twice(tasks.run_hold, run.pk)
    assert _events(run) == ["scheduled", "failed"]
    assert agent.client.list_runs() == []


def test_collecting_twice_stores_every_sample_once(agent, run):
    staging.run_stage(run_id=run.pk)
    start_s = run.start_at.timestamp()
    agent.run_clock(start_s, start_s + 3.0)
    twice(tasks.run_collect, run.pk)
    on_agent = [s["seq"] for s in agent.client.iter_samples(run.agent_run_id)]
    assert list(Sample.objects.filter(run=run).values_list("seq", flat=True)) == on_agent
    assert _events(run) == ["scheduled", "staged", "collecting", "completed"]


def test_the_sweep_twice_with_its_queued_work_does_each_step_once(agent, run, eager_tasks):
    twice(tasks.runs_sweep)
    assert _events(run) == ["scheduled", "staged"]


def test_a_run_its_owner_cancelled_is_not_told_about(agent, run, owner):
    staging.run_stage(run_id=run.pk)
    start_s = run.start_at.timestamp()
    agent.run_clock(start_s, start_s + 1.0)
    tasks.run_collect.apply(args=(run.pk,))  # running here too
    reservation_cancel(reservation=run.reservation, by=owner)
    staging.run_unstage(run_id=run.pk)  # aborted on the robot, then collected
    agent.run_clock(start_s + 1.05, start_s + 2.0)
    tasks.run_collect.apply(args=(run.pk,))
    assert Run.objects.get(pk=run.pk).state == RunState.INTERRUPTED
    mail.outbox.clear()
    twice(events_dispatch_all)
    assert EventCursor.objects.get(handler="run-owner-mail").position > 0  # it was handed
    assert mail.outbox == []


def test_telling_the_owner_twice_sends_one_mail(run):
    staging._fail(run, "the base station refused the run")
    mail.outbox.clear()
    twice(events_dispatch_all)
    assert [m.subject for m in mail.outbox] == [f"Run failed: {run.title}"]
    assert mail.outbox[0].to == [run.reservation.owner.email]
    assert "refused" in mail.outbox[0].body


def _latch_estop(agent) -> None:
    agent.client.stop(user="test", reason="someone on the roof")


@pytest.fixture
def admin_with_mail():
    return UserFactory(username="root", is_staff=True, email="root@example.org")


def test_a_health_check_twice_holds_once(agent, run, mobile):
    _latch_estop(agent)
    twice(tasks.robot_health_check, mobile.pk)
    mobile.refresh_from_db()
    assert "emergency stop latched" in mobile.hold_reason
    assert AuditEvent.objects.filter(action="resource.hold").count() == 1


def test_the_health_sweep_twice_holds_and_the_hold_mails_the_admins_once(
    agent, run, mobile, eager_tasks, admin_with_mail
):
    _latch_estop(agent)
    mail.outbox.clear()
    twice(tasks.robots_health_sweep)  # checks and holds
    twice(tasks.robots_health_sweep)
    twice(events_dispatch_all)  # the hold's event: the mail
    assert AuditEvent.objects.filter(action="resource.hold").count() == 1
    assert [m.to for m in mail.outbox] == [["root@example.org"]]
    assert mail.outbox[0].subject.startswith("mobile-1 out of booking: emergency stop latched")


def test_telling_the_admins_of_a_hold_twice_sends_one_mail(agent, mobile, admin_with_mail):
    assert resource_hold(resource_id=mobile.pk, reason="battery low")
    mail.outbox.clear()
    twice(events_dispatch_all)
    assert [m.subject for m in mail.outbox] == ["mobile-1 out of booking: battery low"]


def test_a_dry_run_delivered_twice_runs_once(owner, mobile, monkeypatch):
    started: list[int] = []
    simulate = dry_run._simulate

    def counted(what: DryRun) -> dict:
        started.append(what.pk)
        return simulate(what)

    monkeypatch.setattr(dry_run, "_simulate", counted)
    tried = dry_run.dry_run_request(user=owner, experiment=ExperimentFactory(owner=owner))
    twice(tasks.dry_run_execute, tried.pk)
    tried.refresh_from_db()
    assert (tried.state, started) == (DryRun.State.COMPLETED, [tried.pk])


def test_a_booking_mail_dispatched_twice_is_sent_once(owner):
    start = timezone.now() + timedelta(days=1)
    reservation_create(
        owner=owner,
        resource=FixedResourceFactory(),
        start_at=start,
        end_at=start + timedelta(hours=1),
    )
    mail.outbox.clear()
    twice(events_dispatch_all)
    assert [m.subject.split(":")[0] for m in mail.outbox] == ["Booking confirmed"]
    # Another pass (beat's) finds the handler's cursor past the event.
    events_dispatch_all.apply()
    assert len(mail.outbox) == 1


def test_reminding_twice_reminds_once(owner, eager_tasks):
    start = timezone.now() + timedelta(minutes=30)
    reservation = reservation_create(
        owner=owner,
        resource=FixedResourceFactory(),
        start_at=start,
        end_at=start + timedelta(hours=1),
    )
    events_dispatch_all.apply()
    mail.outbox.clear()
    twice(reservations_remind)
    twice(events_dispatch_all)
    assert [m.subject.split(":")[0] for m in mail.outbox] == ["Reminder"]
    reminded = Event.objects.filter(type="reservation.starting_soon")
    assert list(reminded.values_list("subject", flat=True)) == [f"reservation:{reservation.pk}"]


def test_sending_webhooks_twice_sends_each_once(owner, tmp_path):
    subscription, secret = webhook_create(owner=owner, url="http://127.0.0.1:9/hook")
    receiver = Receiver(tmp_path, secret)
    receiver.start()
    try:
        webhook_update(subscription=subscription, by=owner, url=receiver.url)
        webhook_test(subscription=subscription, by=owner)
        events_dispatch(name="webhooks")
        twice(webhooks_send)
        assert [line["type"] for line in receiver.received()] == ["webhook.test"]
        sent = WebhookDelivery.objects.get()
        assert (sent.state, sent.attempts) == ("delivered", 1)
    finally:
        receiver.stop()


def test_deleting_expired_keys_twice_deletes_them_once(owner, settings):
    key = IdempotencyKey.objects.create(
        user=owner, key="k", method="POST", path="/", request_hash="h", status=201, response={}
    )
    IdempotencyKey.objects.filter(pk=key.pk).update(
        created_at=timezone.now() - timedelta(seconds=settings.IDEMPOTENCY_KEY_TTL_S + 1)
    )
    kept = IdempotencyKey.objects.create(
        user=owner, key="k2", method="POST", path="/", request_hash="h", status=201, response={}
    )
    twice(idempotency_keys_delete_expired)
    assert list(IdempotencyKey.objects.values_list("pk", flat=True)) == [kept.pk]


def test_deleting_expired_dry_runs_twice_deletes_them_once(owner, settings):
    settings.DRY_RUN_KEEP_S = 60.0
    body = {"title": "t", "segments": [], "limits": {}, "rail_length_m": 1.0}
    DryRun.objects.create(owner=owner, state=DryRun.State.COMPLETED, **body,
                          ended_at=timezone.now() - timedelta(seconds=61))  # fmt: skip
    kept = DryRun.objects.create(owner=owner, state=DryRun.State.COMPLETED, **body,
                                 ended_at=timezone.now())  # fmt: skip
    twice(tasks.dry_runs_delete_expired)
    assert list(DryRun.objects.values_list("pk", flat=True)) == [kept.pk]


@time_machine.travel(datetime(2026, 11, 29, 20, 0, tzinfo=UTC), tick=False)
def test_booking_the_days_self_checks_twice_books_each_once(admin_user, mobile):
    self_check_schedule_set(resource=mobile, by=admin_user, at=time(3, 0))
    twice(tasks.self_checks_book_scheduled)
    check = SelfCheck.objects.get()
    assert check.run.start_at == datetime(2026, 11, 30, 3, 0, tzinfo=UTC)  # Lisbon is UTC now
    assert Reservation.objects.count() == 1


def test_allocating_the_queue_twice_books_each_request_once(owner, mobile):
    from portal.queue.models import QueueRequest, RequestState
    from portal.queue.services import queue_request_submit
    from portal.queue.tasks import queue_allocate_task

    queued = queue_request_submit(
        owner=owner,
        experiment=ExperimentFactory(owner=owner),
        robot=mobile,
        latest_end_at=timezone.now() + timedelta(days=1),
    )
    twice(queue_allocate_task)
    queued.refresh_from_db()
    assert queued.state == RequestState.BOOKED
    assert Reservation.objects.count() == 1
    assert AuditEvent.objects.filter(action="queue.book").count() == 1
    assert QueueRequest.objects.count() == 1


def test_every_task_the_workers_know_is_run_twice_here():
    """A new task must show here that it is safe to run twice."""
    known = {name for name in celery_app.tasks if not name.startswith("celery.")}
    assert known == COVERED, f"not run twice: {sorted(known - COVERED)}"


def test_a_state_change_seen_by_a_late_task_changes_nothing(agent, run):
    """The sweep queues by the database: a task arriving after its step is a no-op."""
    staging.run_stage(run_id=run.pk)
    Run.objects.filter(pk=run.pk).update(state=RunState.COMPLETED)
    for task in (tasks.run_stage, tasks.run_unstage, tasks.run_collect):
        task.apply(args=(run.pk,))
    assert _events(run) == ["scheduled", "staged"]
