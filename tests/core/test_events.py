"""The outbox (``core.events``): an event exists exactly when its change committed, is numbered
in commit order, each subject counted from 1, and read back by its owner alone, in order."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from datetime import timedelta

import jsonschema
import pytest
from django.core import mail
from django.db import connection, transaction
from django.utils import timezone
from rest_framework.test import APIClient

from bookings.choices import Channel
from bookings.leases import scheduler_sweep
from bookings.models import SchedulerLink
from bookings.scheduler import config as scheduler_config
from bookings.services import blackout_create, resource_hold, resource_set_service
from bookings.tasks import reservations_remind
from core import sql
from core.errors import Conflict
from core.events import dispatch, registry, services
from core.events.catalogue import EVENT_TYPES, PAYLOADS
from core.events.models import Event, EventCursor
from core.events.sequence import SEQUENCER_LOCK_KEY, events_sequence
from core.events.services import event_record
from core.openapi import oas30
from portal.runs.models import Run
from portal.runs.services.reservations import (
    reservation_cancel,
    reservation_create,
    reservation_decide,
    reservation_reschedule,
)
from portal.runs.services.transitions import run_transition
from portal.runs.states import Cause, RunState
from tests.factories import ExperimentFactory, FixedResourceFactory, UserFactory

pytestmark = pytest.mark.django_db


def _window(hours_ahead: int = 2):
    start = (timezone.now() + timedelta(hours=hours_ahead)).replace(microsecond=0)
    return start, start + timedelta(minutes=30)


def _numbered() -> list[Event]:
    events_sequence()
    return list(Event.objects.order_by("position"))


def _held_to_the_catalogue(events: list[Event]) -> None:
    for event in events:
        kind = EVENT_TYPES[event.type]
        assert event.version == kind.version
        jsonschema.validate(event.payload, kind.payload)


def test_a_booked_run_and_its_life_are_events_of_its_owner_in_order(owner, mobile, experiment):
    start, end = _window()
    reservation = reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
    )
    run = Run.objects.get(reservation=reservation)
    for state, cause in [
        (RunState.STAGED, Cause.DISPATCH),
        (RunState.RUNNING, Cause.DISPATCH),
        (RunState.COLLECTING, Cause.DISPATCH),
        (RunState.COMPLETED, Cause.DISPATCH),
    ]:
        assert run_transition(run_id=run.pk, to_state=state, cause=cause)
    events = _numbered()
    assert [e.type for e in events] == [
        "reservation.created",
        "run.scheduled",
        "run.staged",
        "run.running",
        "run.collecting",
        "run.completed",
    ]
    assert [e.position for e in events] == list(range(1, 7))
    assert {e.owner_id for e in events} == {owner.pk}
    run_events = [e for e in events if e.subject == f"run:{run.pk}"]
    assert [e.seq for e in run_events] == [1, 2, 3, 4, 5]
    assert [e.payload["from_state"] for e in run_events] == [
        None,
        "scheduled",
        "staged",
        "running",
        "collecting",
    ]
    created = events[0]
    assert created.subject == f"reservation:{reservation.pk}"
    assert created.seq == 1
    assert created.payload["resources"] == [mobile.name]
    assert created.payload["by"] == owner.get_username()
    _held_to_the_catalogue(events)


def test_moves_decisions_and_cancels_say_who_and_through_which_door(owner, admin_user):
    node = FixedResourceFactory(requires_approval=True)
    start, end = _window()
    reservation = reservation_create(
        owner=owner, resource=node, start_at=start, end_at=end, via=Channel.CLI
    )
    reservation_decide(reservation=reservation, by=admin_user, approve=True, via=Channel.ADMIN)
    reservation_reschedule(
        reservation=reservation,
        by=owner,
        start_at=start + timedelta(hours=1),
        end_at=end + timedelta(hours=1),
        via=Channel.API,
    )
    reservation_cancel(reservation=reservation, by=owner, via=Channel.WEB)
    events = _numbered()
    assert [(e.type, e.payload["via"], e.payload["by"], e.seq) for e in events] == [
        ("reservation.created", "cli", "alice", 1),
        ("reservation.approved", "admin", "charlie", 2),
        ("reservation.moved", "api", "alice", 3),
        ("reservation.cancelled", "web", "alice", 4),
    ]
    assert events[0].payload["state"] == "requested"
    assert events[2].payload["start_at"] == (start + timedelta(hours=1)).isoformat()
    _held_to_the_catalogue(events)


def test_a_change_refused_or_rolled_back_leaves_no_event(owner, other, mobile, experiment):
    start, end = _window()
    reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
    )
    before = Event.objects.count()
    with pytest.raises(Conflict):
        reservation_create(
            owner=other,
            resource=mobile,
            start_at=start,
            end_at=end,
            experiment=ExperimentFactory(owner=other),
        )
    node = FixedResourceFactory()

    def book_then_fail() -> None:
        with transaction.atomic():
            reservation_create(
                owner=owner, resource=node, start_at=end, end_at=end + timedelta(hours=1)
            )
            raise RuntimeError("rolled back")

    with pytest.raises(RuntimeError, match="rolled back"):
        book_then_fail()
    assert Event.objects.count() == before


def test_an_event_of_no_known_type_is_refused(owner):
    with pytest.raises(ValueError, match="not an event type"), transaction.atomic():
        event_record(subject="x:1", type="x.happened", payload={}, owner_id=owner.pk)
    assert not Event.objects.exists()


@pytest.mark.django_db(transaction=True)
def test_an_event_outside_the_transaction_of_its_change_is_refused(owner):
    with pytest.raises(RuntimeError, match="inside the transaction"):
        event_record(subject="run:1", type="run.running", payload={}, owner_id=owner.pk)
    assert not Event.objects.exists()


@pytest.mark.django_db(transaction=True)
def test_an_event_committed_late_is_numbered_after_those_read_before_it(owner):
    """The row written first but committed last must not fall behind a reader's position."""
    written = threading.Event()
    commit = threading.Event()

    def slow_writer() -> None:
        try:
            with transaction.atomic():
                event_record(subject="run:1", type="run.running", payload={}, owner_id=owner.pk)
                written.set()
                assert commit.wait(30)
        finally:
            connection.close()

    writer = threading.Thread(target=slow_writer)
    writer.start()
    assert written.wait(30)
    with transaction.atomic():
        quick = event_record(subject="run:2", type="run.running", payload={}, owner_id=owner.pk)
    events_sequence()
    seen = list(Event.objects.filter(position__isnull=False))
    assert [e.pk for e in seen] == [quick.pk]  # the slow one, uncommitted, is not numbered
    commit.set()
    writer.join(30)
    assert not writer.is_alive()
    events_sequence()
    late = Event.objects.exclude(pk=quick.pk).get()
    assert late.pk < quick.pk  # written first
    assert late.position == 2  # numbered after what a reader may already have seen
    assert late.seq == 1


@contextlib.contextmanager
def _held_elsewhere(take: Callable[[], object]) -> Iterator[threading.Thread]:
    """``take`` done in a transaction of another thread (its own connection), which holds
    what it took until the block ends: a process frozen inside it, or another pass."""
    held, release = threading.Event(), threading.Event()

    def holder() -> None:
        try:
            with transaction.atomic():
                take()
                held.set()
                assert release.wait(30)
        finally:
            connection.close()

    thread = threading.Thread(target=holder)
    thread.start()
    try:
        assert held.wait(30)
        yield thread
    finally:
        release.set()
        thread.join(30)


def test_a_sequencer_frozen_inside_its_lock_holds_no_one_up(owner, monkeypatch):
    """A process stopped while it holds the sequencer's lock (a SIGSTOPped mail worker did):
    another caller gives up after its bounded wait instead of waiting for it, and numbers
    the events once the lock is free again."""
    assert connection.vendor == "postgresql"
    monkeypatch.setattr("core.events.sequence.SEQUENCER_WAIT_S", 0.2)
    with _held_elsewhere(lambda: sql.advisory_xact_lock(SEQUENCER_LOCK_KEY)) as holder:
        with transaction.atomic():
            event_record(subject="run:1", type="run.running", payload={}, owner_id=owner.pk)
        assert events_sequence() == 0  # gave up waiting: nothing numbered, nothing blocked
    assert not holder.is_alive()
    assert events_sequence() == 1


def test_the_sequencer_numbers_a_backlog_in_passes_and_then_nothing(owner, monkeypatch):
    monkeypatch.setattr("core.events.sequence.SEQUENCE_BATCH", 3)
    with transaction.atomic():
        for n in range(7):
            event_record(subject=f"run:{n % 2}", type="run.running", payload={}, owner_id=owner.pk)
    assert events_sequence() == 7
    assert events_sequence() == 0
    events = list(Event.objects.order_by("id"))
    assert [e.position for e in events] == list(range(1, 8))
    assert [e.seq for e in events] == [1, 1, 2, 2, 3, 3, 4]


# --- GET /api/v1/events/ ------------------------------------------------------------------------


def _book(owner, **kwargs):
    start, end = _window(**kwargs)
    return reservation_create(
        owner=owner, resource=FixedResourceFactory(), start_at=start, end_at=end
    )


def test_a_user_reads_their_own_events_after_a_position_and_no_one_elses(
    owner, other, api, client_for
):
    mine = _book(owner)
    _book(other, hours_ahead=3)
    reservation_cancel(reservation=mine, by=owner)
    answer = api.get("/api/v1/events/")
    assert answer.status_code == 200, answer.content
    body = answer.json()
    assert [(e["type"], e["subject"]) for e in body["events"]] == [
        ("reservation.created", f"reservation:{mine.pk}"),
        ("reservation.cancelled", f"reservation:{mine.pk}"),
    ]
    first, second = body["events"]
    assert body["last"] == second["id"] > first["id"]
    assert first["data"]["reservation"] == mine.pk
    assert (first["seq"], second["seq"], first["version"]) == (1, 2, 1)
    after = api.get("/api/v1/events/", {"after": first["id"]}).json()
    assert [e["id"] for e in after["events"]] == [second["id"]]
    nothing = api.get("/api/v1/events/", {"after": body["last"]}).json()
    assert nothing == {"events": [], "last": body["last"]}
    only = api.get("/api/v1/events/", {"type": "reservation.cancelled"}).json()
    assert [e["type"] for e in only["events"]] == ["reservation.cancelled"]
    theirs = client_for(other).get("/api/v1/events/").json()
    assert {e["data"]["by"] for e in theirs["events"]} == {"bob"}
    second_of_mine = _book(owner, hours_ahead=5)
    about = api.get("/api/v1/events/", {"subject": f"reservation:{second_of_mine.pk}"}).json()
    assert [e["subject"] for e in about["events"]] == [f"reservation:{second_of_mine.pk}"]
    # Someone else's subject is no way in: nothing of theirs comes back.
    bobs = client_for(other).get("/api/v1/events/", {"subject": f"reservation:{mine.pk}"})
    assert bobs.json()["events"] == []


@pytest.mark.parametrize(
    "query",
    [
        {"after": "-1"},
        {"after": "x"},
        {"wait": "21"},
        {"limit": "0"},
        {"type": "run.exploded"},
        {"subject": "r" * 81},
    ],
)
def test_a_bad_question_is_answered_400_and_says_which_parameter(api, query):
    answer = api.get("/api/v1/events/", query)
    assert answer.status_code == 400, answer.content
    assert set(answer.json()["fields"]) == set(query)


def test_events_need_a_signed_in_user(client_for):
    assert client_for(None).get("/api/v1/events/").status_code in (401, 403)


@pytest.mark.django_db(transaction=True)
def test_a_long_poll_answers_as_soon_as_an_event_commits(owner, api, monkeypatch):
    answers: list = []
    waiting = threading.Event()

    class Clock:
        """The selector's clock, telling the test when the poll found nothing and waits."""

        monotonic = staticmethod(time.monotonic)

        @staticmethod
        def sleep(seconds: float) -> None:
            waiting.set()
            time.sleep(seconds)

    monkeypatch.setattr("core.events.selectors.time", Clock)

    def poll() -> None:
        try:
            answers.append(api.get("/api/v1/events/", {"wait": "20"}))
        finally:
            connection.close()

    poller = threading.Thread(target=poll)
    poller.start()
    assert waiting.wait(20), "the poll never waited"
    mine = _book(owner)
    poller.join(25)
    assert not poller.is_alive()
    [answer] = answers
    assert answer.status_code == 200
    assert [e["data"]["reservation"] for e in answer.json()["events"]] == [mine.pk]


# --- A robot's and the scheduler link's events: staff's ------------------------------------------


def test_a_robot_held_and_released_is_an_event_for_staff_only(
    mobile, admin_user, api, staff_verified_client
):
    assert resource_hold(resource_id=mobile.pk, reason="emergency stop latched on the roof")
    assert not resource_hold(resource_id=mobile.pk, reason="again")  # held already: no event
    resource_set_service(resource=mobile, by=admin_user, enabled=True, reason="checked it")
    events = _numbered()
    assert [(e.type, e.subject, e.owner_id, e.payload["by"]) for e in events] == [
        ("robot.held", f"robot:{mobile.name}", None, None),
        ("robot.released", f"robot:{mobile.name}", None, "charlie"),
    ]
    assert events[0].payload["reason"] == "emergency stop latched on the roof"
    _held_to_the_catalogue(events)
    assert api.get("/api/v1/events/").json()["events"] == []
    staff = staff_verified_client.get("/api/v1/events/").json()["events"]
    assert [e["type"] for e in staff] == ["robot.held", "robot.released"]
    # Staff whose session has not passed its second factor read as the plain user they are.
    unverified = APIClient()
    unverified.force_authenticate(user=UserFactory(username="dora", is_staff=True))
    assert unverified.get("/api/v1/events/").json()["events"] == []


def test_the_scheduler_link_going_down_and_up_is_one_event_each(settings, owner):
    settings.SCHEDULER = scheduler_config.from_env({"SCHEDULER_URL": "http://127.0.0.1:9"})
    assert scheduler_sweep() is None
    assert scheduler_sweep() is None  # still down: said once
    link = SchedulerLink.objects.get()
    link.last_error_at = None  # as if the failures were before the last success
    link.last_success_at = timezone.now()
    link.save()
    assert scheduler_sweep() is None
    events = _numbered()
    assert [(e.type, e.subject, e.seq) for e in events] == [
        ("scheduler.link_down", "scheduler", 1),
        ("scheduler.link_down", "scheduler", 2),
    ]
    assert "since" not in events[0].payload
    assert events[1].payload["since"] == link.last_success_at.isoformat()
    _held_to_the_catalogue(events)


def test_a_booking_under_maintenance_and_about_to_start_is_flagged_and_reminded_in_events(
    owner, admin_user, settings, eager_tasks, django_capture_on_commit_callbacks
):
    """The reservation's own events, held to the catalogue; its e-mails are their reactions
    (``bookings.handlers``): the owner's and, for a problem, the admins'."""
    node = FixedResourceFactory()
    start = timezone.now() + timedelta(minutes=20)
    with django_capture_on_commit_callbacks(execute=True):
        reservation = reservation_create(
            owner=owner, resource=node, start_at=start, end_at=start + timedelta(minutes=30)
        )
    mail.outbox.clear()
    with django_capture_on_commit_callbacks(execute=True):
        blackout, _ = blackout_create(
            by=admin_user,
            start_at=start,
            end_at=start + timedelta(hours=1),
            reason="antenna swap",
            resources=[node],
        )
    settings.RESERVATION_REMINDER_LEAD_S = 3600
    with django_capture_on_commit_callbacks(execute=True):
        reservations_remind()
    events = [e for e in _numbered() if e.subject == f"reservation:{reservation.pk}"]
    assert [(e.type, e.seq, e.owner_id) for e in events] == [
        ("reservation.created", 1, owner.pk),
        ("reservation.flagged", 2, owner.pk),
        ("reservation.starting_soon", 3, owner.pk),
    ]
    assert events[1].payload["problem"] == "maintenance"
    assert events[1].payload["blackout"] == blackout.pk
    assert "antenna swap" in events[1].payload["note"]
    _held_to_the_catalogue(events)
    assert [(m.subject.split(":")[0], sorted(m.to)) for m in mail.outbox] == [
        ("Maintenance overlaps a booking", sorted([owner.email, admin_user.email])),
        ("Reminder", [owner.email]),
    ]


def test_the_api_schema_documents_each_payload_as_the_catalogue_states_it(api):
    """The OpenAPI description's payload components are the catalogue's schemas (which every
    event written is held to, above), and an event's ``data`` is one of them."""
    schema = api.get("/api/schema/", HTTP_ACCEPT="application/json").json()
    components = schema["components"]["schemas"]
    for name, (payload, types) in PAYLOADS.items():
        documented = components[name]
        assert documented["properties"] == oas30(payload)["properties"], name
        assert documented["required"] == payload["required"], name
        assert all(f"`{t}`" in documented["description"] for t in types)
    data = components["Event"]["properties"]["data"]  # EventOutput, as the schema names it
    assert data["oneOf"] == [{"$ref": f"#/components/schemas/{name}"} for name in PAYLOADS]
    assert set(EVENT_TYPES) == {t for _, types in PAYLOADS.values() for t in types}


# --- Reactions: core.events.dispatch -------------------------------------------------------------


@pytest.fixture
def seen(monkeypatch):
    """A handler of run.running and run.failed that records what it is handed, and fails once
    on the event numbered in ``fail_on``."""
    handled: list[int] = []
    fail_on: set[int] = set()

    def record(event: Event) -> None:
        handled.append(event.payload["run"])
        if event.payload["run"] in fail_on:
            fail_on.discard(event.payload["run"])
            raise OSError("mail server down")

    monkeypatch.setattr(registry, "_HANDLERS", {})
    dispatch.handler("recorder", types=["run.running", "run.failed"])(record)
    return handled, fail_on


def _write(owner, *pairs: tuple[str, int]) -> None:
    with transaction.atomic():
        for type_, run in pairs:
            event_record(subject=f"run:{run}", type=type_, payload={"run": run}, owner_id=owner.pk)


def test_a_handler_is_handed_its_types_in_order_and_again_after_it_failed(owner, seen):
    handled, fail_on = seen
    _write(owner, ("run.running", 1), ("run.staged", 2), ("run.failed", 3), ("run.running", 4))
    fail_on.add(3)
    with pytest.raises(OSError, match="mail server down"):
        dispatch.events_dispatch(name="recorder")
    assert handled == [1, 3]  # the staged event is not its type; 3 failed
    assert dispatch.events_dispatch(name="recorder") == 2
    assert handled == [1, 3, 3, 4]  # 3 again, then on
    assert dispatch.events_dispatch(name="recorder") == 0
    assert EventCursor.objects.get(handler="recorder").position == 4


def test_one_failing_handler_does_not_stop_the_others(owner, seen, monkeypatch):
    handled, fail_on = seen
    others: list[str] = []
    dispatch.handler("other", types=["run.failed"])(lambda event: others.append(event.type))
    _write(owner, ("run.failed", 7))
    fail_on.add(7)
    assert dispatch.events_dispatch_all() == {"other": 1, "recorder": 0}
    assert dispatch.events_dispatch_all() == {"other": 0, "recorder": 1}
    assert others == ["run.failed"]
    assert handled == [7, 7]


@pytest.mark.django_db(transaction=True)
def test_two_passes_of_one_handler_never_overlap(owner, seen):
    handled, _ = seen
    _write(owner, ("run.running", 1))
    EventCursor.objects.create(handler="recorder")
    # Another pass, holding the handler's cursor.
    with _held_elsewhere(lambda: EventCursor.objects.select_for_update().get(handler="recorder")):
        assert dispatch.events_dispatch(name="recorder") == 0  # it leaves at once
    assert handled == []
    assert dispatch.events_dispatch(name="recorder") == 1


def test_a_handler_of_no_known_type_is_refused():
    with pytest.raises(ValueError, match="not event types"):
        dispatch.handler("typo", types=["run.finished"])


def test_only_an_event_some_handler_wants_wakes_the_handlers_at_commit(
    owner, seen, django_capture_on_commit_callbacks
):
    with django_capture_on_commit_callbacks() as unwanted:
        _write(owner, ("run.staged", 1))
    with django_capture_on_commit_callbacks() as wanted:
        _write(owner, ("run.failed", 2))
    assert unwanted == []
    assert [c.queues for c in wanted] == [{None}]


def test_a_transaction_wakes_each_queue_once_however_many_events_it_records(
    owner, seen, django_capture_on_commit_callbacks, monkeypatch
):
    woken: list[str | None] = []
    monkeypatch.setattr(services, "_wake_handlers", woken.append)
    dispatch.handler("pusher", types=["run.running"], queue="runs")(lambda event: None)
    with django_capture_on_commit_callbacks(execute=True) as callbacks:
        _write(owner, ("run.running", 1), ("run.failed", 2), ("run.running", 3))
    assert len(callbacks) == 1
    assert sorted(woken, key=str) == [None, "runs"]
    # A savepoint rolled back takes its wake with it; the next event begins another.
    woken.clear()
    with django_capture_on_commit_callbacks(execute=True), transaction.atomic():
        try:
            with transaction.atomic():
                event_record(
                    subject="run:4", type="run.failed", payload={"run": 4}, owner_id=owner.pk
                )
                raise RuntimeError("refused")
        except RuntimeError:
            pass
        event_record(subject="run:5", type="run.failed", payload={"run": 5}, owner_id=owner.pk)
    assert woken == [None]


def test_a_savepoint_released_wakes_with_its_transaction_and_a_block_beside_on_its_own(
    owner, seen, django_capture_on_commit_callbacks, monkeypatch
):
    # A booking writes its reservation in a block of its own, then its run: one wake.
    woken: list[str | None] = []
    monkeypatch.setattr(services, "_wake_handlers", woken.append)
    with django_capture_on_commit_callbacks(execute=True) as callbacks, transaction.atomic():
        _write(owner, ("run.failed", 1))
        event_record(subject="run:2", type="run.failed", payload={"run": 2}, owner_id=owner.pk)
    assert len(callbacks) == 1
    assert woken == [None]
    # A block beside an earlier one whose batch has not run (a test's "transactions" inside
    # its own) begins its own, which its caller sees and runs.
    woken.clear()
    with django_capture_on_commit_callbacks() as earlier:
        _write(owner, ("run.failed", 3))
    with django_capture_on_commit_callbacks(execute=True) as later:
        _write(owner, ("run.failed", 4))
    assert (len(earlier), len(later), woken) == (1, 1, [None])


def test_a_handler_found_inactive_is_asked_once_per_transaction(
    owner, seen, django_capture_on_commit_callbacks
):
    asked: list[str] = []

    def active() -> bool:
        asked.append("asked")
        return False

    dispatch.handler("hooks", types=["run.staged", "run.running"], queue="hooks", active=active)(
        lambda event: None
    )
    with django_capture_on_commit_callbacks() as woken:
        _write(owner, ("run.staged", 1), ("run.staged", 2), ("run.running", 3))
    assert asked == ["asked"]
    assert [c.queues for c in woken] == [{None}]  # the recorder's, for run.running
    _write(owner, ("run.staged", 4))  # another transaction asks again
    assert asked == ["asked", "asked"]


def test_a_handler_of_its_own_queue_is_woken_there_and_passed_by_that_queues_pass(
    owner, seen, django_capture_on_commit_callbacks
):
    handled, _ = seen
    pushed: list[int] = []
    dispatch.handler("pusher", types=["run.failed"], queue="runs")(
        lambda event: pushed.append(event.payload["run"])
    )
    with django_capture_on_commit_callbacks() as woken:
        _write(owner, ("run.failed", 1))
    assert [sorted(str(q) for q in c.queues) for c in woken] == [["None", "runs"]]
    assert dispatch.events_dispatch_all(queue="runs") == {"pusher": 1}
    assert (pushed, handled) == ([1], [])
    assert dispatch.events_dispatch_all() == {"recorder": 1}
    assert handled == [1]


def test_a_handler_from_the_end_starts_after_the_old_events_and_takes_the_recent(owner, seen):
    _write(owner, ("run.failed", 1), ("run.failed", 2))
    events_sequence()
    Event.objects.filter(payload__run=1).update(
        occurred_at=timezone.now() - timedelta(seconds=dispatch.FROM_END_RECENT_S + 60)
    )
    late: list[int] = []
    dispatch.handler("late", types=["run.failed"], from_end=True)(
        lambda event: late.append(event.payload["run"])
    )
    assert dispatch.events_dispatch(name="late") == 1
    assert late == [2]  # not the old one
    _write(owner, ("run.failed", 3))
    assert dispatch.events_dispatch(name="late") == 1
    assert late == [2, 3]
