"""Bookings with scheduler-owned nodes: one lease, all or nothing, mirrored and reconciled.

The stand-in broker runs as a separate process (``conftest.py``); the portal's services run
here against the test database.
"""

from __future__ import annotations

import threading
import time
import uuid
from dataclasses import replace
from datetime import datetime, timedelta

import pytest
from django.core import mail
from django.db import connection, transaction
from django.utils import timezone

from bookings import leases
from bookings.calendar import calendar_entries
from bookings.choices import ReservationState
from bookings.models import Reservation, Resource, SchedulerLease, SchedulerLink
from bookings.scheduler import LeaseStatus
from bookings.scheduler import config as scheduler_config
from bookings.selectors import resource_free_intervals
from bookings.services import fixed_node_names_from_scheduler, reservation_complete
from bookings.services import reservations as without_run
from bookings.tasks import lease_cancel, scheduler_sweep
from core.errors import Conflict, NotAllowed
from portal.runs.models import Run
from portal.runs.services.reservations import (
    reservation_cancel,
    reservation_check,
    reservation_create,
    reservation_decide,
    reservation_reschedule,
)
from tests.bookings.scheduler.conftest import Standin
from tests.conftest import sign_in_with_second_factor
from tests.factories import ExperimentFactory, FixedResourceFactory
from tests.runs.test_tasks_twice import twice
from tests.sqlite import run_on_sqlite

pytestmark = pytest.mark.django_db


@pytest.fixture
def linked(settings, standin: Standin, mobile) -> Standin:
    """The portal with the stand-in as its scheduler and six fixed nodes it owns."""
    settings.SCHEDULER = replace(standin.config, read_timeout_s=2.0, connect_timeout_s=1.0)
    for i in range(1, 7):
        FixedResourceFactory(name=f"node-{i:02d}")
    return standin


@pytest.fixture
def slot() -> tuple[datetime, datetime]:
    start = timezone.now().replace(microsecond=0) + timedelta(days=1)
    return start, start + timedelta(minutes=30)


def _nodes(*numbers: int):
    return [Resource.objects.get(name=f"node-{n:02d}") for n in numbers]


def _broker_leases(standin: Standin):
    with standin.scheduler() as scheduler:
        return scheduler.list_leases(statuses=tuple(LeaseStatus))


def _live(standin: Standin):
    return [lease for lease in _broker_leases(standin) if lease.holds_nodes]


def test_a_booking_of_the_robot_and_four_nodes_holds_one_lease_of_the_four(
    linked, owner, mobile, slot
):
    experiment = ExperimentFactory(owner=owner)
    reservation = reservation_create(
        owner=owner,
        resources=[mobile, *_nodes(1, 2, 3, 4)],
        start_at=slot[0],
        end_at=slot[1],
        experiment=experiment,
    )
    [lease] = _live(linked)
    assert sorted(lease.component_names) == ["node-01", "node-02", "node-03", "node-04"]
    assert lease.name == f"amazing-reservation-{reservation.public_id}"
    assert (lease.valid_from, lease.valid_until) == slot
    assert reservation.lease_uuid == lease.uuid
    assert SchedulerLease.objects.get(uuid=lease.uuid).reservation == reservation
    assert Run.objects.filter(reservation=reservation).exists()


def test_a_booking_without_scheduler_owned_nodes_asks_the_scheduler_nothing(
    linked, owner, mobile, slot
):
    linked.faults(unavailable=True)  # would fail any booking that asked it
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=slot[0],
        end_at=slot[1],
        experiment=ExperimentFactory(owner=owner),
    )
    assert reservation.lease_uuid == ""


def test_a_lease_made_elsewhere_refuses_the_booking_naming_it(linked, owner, slot):
    linked.seed(
        name="r2lab-campaign",
        valid_from=slot[0].isoformat(),
        valid_until=slot[1].isoformat(),
        components=[{"name": "node-02"}],
        account_attributes={"name": "someone"},
    )
    with pytest.raises(
        Conflict, match="node-02 is leased on the testbed scheduler by someone"
    ) as e:
        without_run.reservation_create(
            owner=owner, resources=_nodes(1, 2), start_at=slot[0], end_at=slot[1]
        )
    assert "r2lab-campaign" in e.value.message
    assert not Reservation.objects.exists()
    assert len(_live(linked)) == 1  # only theirs


def test_a_refusal_by_the_scheduler_leaves_nothing_behind_and_names_the_node(
    linked, owner, slot, monkeypatch, client_for
):
    linked.seed(
        name="made-a-moment-ago",
        valid_from=slot[0].isoformat(),
        valid_until=slot[1].isoformat(),
        components=[{"name": "node-03"}],
        account_attributes={"name": "someone"},
    )
    # The lease came after the portal's look at the scheduler: the scheduler itself refuses.
    monkeypatch.setattr("bookings.services.reservations.leases_refresh", lambda **kwargs: None)
    response = client_for(owner).post(
        "/api/v1/reservations/",
        {
            "resources": ["node-01", "node-03"],
            "start_at": slot[0].isoformat(),
            "end_at": slot[1].isoformat(),
        },
        format="json",
    )
    assert response.status_code == 409, response.content
    assert "node-03" in response.json()["detail"]
    # The scheduler's refusal, not the portal's (which would name the lease): the look is skipped.
    assert "The testbed scheduler refused the lease" in response.json()["detail"]
    assert not Reservation.objects.exists()
    assert [lease.name for lease in _live(linked)] == ["made-a-moment-ago"]


@pytest.mark.parametrize("fault", [{"unavailable": True}, {"delay_s": 3.0}])
def test_a_scheduler_down_or_too_slow_is_a_503_and_nothing_is_made(
    linked, owner, slot, client_for, fault
):
    linked.faults(**fault)
    response = client_for(owner).post(
        "/api/v1/reservations/",
        {"resources": ["node-01"], "start_at": slot[0].isoformat(), "end_at": slot[1].isoformat()},
        format="json",
    )
    assert response.status_code == 503, response.content
    assert response.json()["error"] == "scheduler_unavailable"
    assert "nothing was booked" in response.json()["detail"]
    linked.faults(unavailable=False, delay_s=0)
    assert not Reservation.objects.exists()
    assert _live(linked) == []


def test_a_failure_after_the_lease_cancels_it_at_once(linked, owner, slot, monkeypatch):
    def broken(**kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr("bookings.services.reservations.lease_record", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        without_run.reservation_create(
            owner=owner, resources=_nodes(1), start_at=slot[0], end_at=slot[1]
        )
    assert not Reservation.objects.exists()
    [lease] = _broker_leases(linked)
    assert lease.status == LeaseStatus.CANCELLED


def test_a_failure_of_the_run_after_the_booking_gives_the_lease_back(
    linked, owner, mobile, slot, monkeypatch
):
    def broken(**kwargs):
        raise RuntimeError("no run")

    monkeypatch.setattr("portal.runs.services.reservations.run_create", broken)
    with pytest.raises(RuntimeError, match="no run"):
        reservation_create(
            owner=owner,
            resources=[mobile, *_nodes(1)],
            start_at=slot[0],
            end_at=slot[1],
            experiment=ExperimentFactory(owner=owner),
        )
    assert not Reservation.objects.exists()
    assert _live(linked) == []


def test_the_sweep_cancels_an_orphan_but_never_a_lease_still_being_booked(linked, slot):
    public_ids = [uuid.uuid4(), uuid.uuid4()]
    with linked.scheduler() as scheduler:
        for public_id in public_ids:
            scheduler.create_lease(
                name=leases.lease_name_for(public_id),
                valid_from=slot[0],
                valid_until=slot[1],
                component_names=["node-05"] if public_id == public_ids[0] else ["node-06"],
            )
    booking = threading.Event()
    release = threading.Event()

    def book_slowly() -> None:
        # Another connection is in the middle of booking the second one.
        with transaction.atomic():
            leases.booking_guard(public_ids[1])
            booking.set()
            release.wait(10)
        connection.close()

    thread = threading.Thread(target=book_slowly)
    thread.start()
    try:
        assert booking.wait(10)
        result = leases.scheduler_sweep()
    finally:
        release.set()
        thread.join()
    assert result is not None
    assert result.orphans_cancelled == 1
    live = {lease.name for lease in _live(linked)}
    assert live == {leases.lease_name_for(public_ids[1])}
    # Once that booking is over (here: it never committed), the next sweep cancels it too.
    assert leases.scheduler_sweep().orphans_cancelled == 1
    assert _live(linked) == []


def test_the_sweep_leaves_the_lease_of_a_booking_whose_run_completed_before_its_end(
    linked, owner, slot
):
    """Found by the soak: a run that completed early marks its booking completed, and the
    sweep took that booking's lease for an orphan and cancelled it — the fixed nodes given
    away in the middle of the researcher's slot."""
    kept = without_run.reservation_create(
        owner=owner, resources=_nodes(1), start_at=slot[0], end_at=slot[1]
    )
    withdrawn = without_run.reservation_create(
        owner=owner, resources=_nodes(2), start_at=slot[0], end_at=slot[1]
    )
    assert reservation_complete(reservation_id=kept.pk)
    # A cancelled booking whose lease could not be given back at once: the sweep's to cancel.
    Reservation.objects.filter(pk=withdrawn.pk).update(state=ReservationState.CANCELLED)
    result = leases.scheduler_sweep()
    assert result is not None
    assert result.orphans_cancelled == 1
    assert [lease.uuid for lease in _live(linked)] == [kept.lease_uuid]


# Its threads' connections commit: the test's rows must be committed for them, and flushed.
@pytest.mark.django_db(transaction=True)
def test_the_sweep_waits_for_a_bookings_mirror_of_the_leases_to_commit(linked, slot):
    """A booking mirrors the leases inside its transaction, the sweep inside its own: each
    locks many lease rows, and two at once deadlocked. The sweep now waits for the booking's
    transaction to end before it mirrors."""
    linked.seed(
        name="elsewhere",
        valid_from=slot[0].isoformat(),
        valid_until=slot[1].isoformat(),
        components=[{"name": "node-03"}],
        account_attributes={"name": "someone"},
    )
    mirrored, release, swept = threading.Event(), threading.Event(), threading.Event()
    sweep_connected = threading.Event()
    # Each thread's database backend: the server is shared with other tests' databases, whose
    # own advisory locks must not count as this sweep waiting.
    backend_pid: dict[str, int] = {}

    def own_backend_pid() -> int:
        with connection.cursor() as cursor:
            cursor.execute("SELECT pg_backend_pid()")
            return int(cursor.fetchone()[0])

    def booking() -> None:
        with transaction.atomic():
            backend_pid["booking"] = own_backend_pid()
            leases.leases_refresh(start_at=slot[0], end_at=slot[1])
            mirrored.set()
            release.wait(30)
        connection.close()

    def sweep() -> None:
        backend_pid["sweep"] = own_backend_pid()
        sweep_connected.set()
        leases.scheduler_sweep()
        swept.set()
        connection.close()

    def sweep_waiting() -> bool:
        """The sweep's backend waits for an advisory lock the booking's backend holds."""
        with connection.cursor() as cursor:
            cursor.execute(
                "SELECT count(*) FROM pg_locks WHERE locktype = 'advisory' AND NOT granted"
                " AND pid = %s AND %s = ANY(pg_blocking_pids(pid))",
                [backend_pid["sweep"], backend_pid["booking"]],
            )
            return bool(cursor.fetchone()[0])

    threads = [threading.Thread(target=booking), threading.Thread(target=sweep)]
    threads[0].start()
    try:
        assert mirrored.wait(30)
        threads[1].start()
        assert sweep_connected.wait(30)
        deadline = time.monotonic() + 30
        while not sweep_waiting():
            assert not swept.is_set(), "the sweep mirrored while the booking's mirror stood"
            assert time.monotonic() < deadline, "the sweep never waited"
            time.sleep(0.05)
    finally:
        release.set()
        for thread in threads:
            thread.join(30)
    assert swept.is_set()
    assert SchedulerLease.objects.filter(name="elsewhere", holds=True).count() == 1


def test_a_booking_cancels_the_portals_own_orphan_in_its_way_but_no_other_lease(
    linked, owner, slot
):
    orphan, being_booked = uuid.uuid4(), uuid.uuid4()
    with linked.scheduler() as scheduler:
        for public_id, node in ((orphan, "node-05"), (being_booked, "node-06")):
            scheduler.create_lease(
                name=leases.lease_name_for(public_id),
                valid_from=slot[0],
                valid_until=slot[1],
                component_names=[node],
            )
    # Named like the portal's, but another account's: not the portal's to cancel.
    linked.seed(
        name=leases.lease_name_for(uuid.uuid4()),
        valid_from=slot[0].isoformat(),
        valid_until=slot[1].isoformat(),
        components=[{"name": "node-04"}],
        account_attributes={"name": "someone"},
    )
    booking = threading.Event()
    release = threading.Event()

    def book_slowly() -> None:
        # Another connection is between the lease of ``being_booked`` and its commit.
        with transaction.atomic():
            leases.booking_guard(being_booked)
            booking.set()
            release.wait(10)
        connection.close()

    thread = threading.Thread(target=book_slowly)
    thread.start()
    try:
        assert booking.wait(10)
        reservation = without_run.reservation_create(
            owner=owner, resources=_nodes(5), start_at=slot[0], end_at=slot[1]
        )
        with pytest.raises(Conflict, match="node-06 is leased on the testbed scheduler"):
            without_run.reservation_create(
                owner=owner, resources=_nodes(6), start_at=slot[0], end_at=slot[1]
            )
    finally:
        release.set()
        thread.join()
    with pytest.raises(Conflict, match="node-04 is leased on the testbed scheduler by someone"):
        without_run.reservation_create(
            owner=owner, resources=_nodes(4), start_at=slot[0], end_at=slot[1]
        )
    by_name = {lease.name: lease for lease in _broker_leases(linked)}
    assert by_name[leases.lease_name_for(orphan)].status == LeaseStatus.CANCELLED
    assert by_name[leases.lease_name_for(being_booked)].holds_nodes
    [own] = [lease for lease in _live(linked) if lease.uuid == reservation.lease_uuid]
    assert own.component_names == ("node-05",)
    assert SchedulerLease.objects.get(name=leases.lease_name_for(orphan)).status == "cancelled"


SQLITE_ORPHAN = r"""
import uuid
from datetime import timedelta
from django.utils import timezone
from bookings import leases
from bookings.models import Resource
from bookings.services import reservation_create
from core.accounts.models import User

node = Resource.objects.create(name="node-05", kind="fixed")
alice = User.objects.create_user("alice")
start = timezone.now().replace(microsecond=0) + timedelta(days=1)
end = start + timedelta(hours=1)
with leases.scheduler_client() as scheduler:
    orphan = scheduler.create_lease(
        name=leases.lease_name_for(uuid.uuid4()), valid_from=start, valid_until=end,
        component_names=["node-05"],
    )
booked = reservation_create(owner=alice, resource=node, start_at=start, end_at=end)
with leases.scheduler_client() as scheduler:
    for lease in scheduler.list_leases(window_start=start, window_end=end, statuses=("cancelled",)):
        print("cancelled:", lease.uuid == orphan.uuid)
print("booked:", booked.lease_uuid not in ("", orphan.uuid))
"""


def test_on_sqlite_a_booking_cancels_the_portals_own_orphan_without_waiting(
    standin_409, tmp_path, monkeypatch
):
    # SQLite has no advisory locks; inside a booking's IMMEDIATE transaction no other
    # booking is under way, so the sweep's grace is not needed there.
    standin_409.reset()
    monkeypatch.setenv("SCHEDULER_URL", standin_409.url)
    output = run_on_sqlite(SQLITE_ORPHAN, tmp_path)
    assert "cancelled: True" in output
    assert "booked: True" in output


def test_leases_made_elsewhere_show_as_busy_and_block_the_live_check(linked, owner, slot):
    linked.seed(
        name="fit-session",
        valid_from=slot[0].isoformat(),
        valid_until=(slot[0] + timedelta(minutes=10)).isoformat(),
        components=[{"name": "node-04"}],
        account_attributes={"name": "fit"},
    )
    assert leases.scheduler_sweep().leases_seen == 1
    [node] = _nodes(4)
    entries = calendar_entries(
        viewer=owner, start_at=slot[0] - timedelta(hours=1), end_at=slot[1], now=timezone.now()
    )
    assert [e.title for e in entries if e.kind == "lease"] == [
        "Leased on the testbed scheduler: fit-session [node-04]"
    ]
    free = resource_free_intervals(resource=node, start_at=slot[0], end_at=slot[1])
    assert free == [(slot[0] + timedelta(minutes=10), slot[1])]
    check = reservation_check(
        owner=owner, resources=[node], start_at=slot[0], end_at=slot[1], experiment=None
    )
    assert [p.code for p in check.problems] == ["lease"]
    assert check.leases_from == "scheduler"


def test_the_live_check_asks_the_scheduler_as_booking_does(linked, owner, other, slot):
    # A portal booking of node-06, which holds a lease of its own.
    without_run.reservation_create(
        owner=other, resources=_nodes(6), start_at=slot[0], end_at=slot[1]
    )
    # A lease made elsewhere a moment ago: nothing has mirrored it yet.
    linked.seed(
        name="just-now",
        valid_from=slot[0].isoformat(),
        valid_until=slot[1].isoformat(),
        components=[{"name": "node-05"}],
        account_attributes={"name": "fit"},
    )
    check = reservation_check(
        owner=owner, resources=_nodes(5, 6), start_at=slot[0], end_at=slot[1], experiment=None
    )
    assert (check.leases_from, check.notice) == ("scheduler", "")
    # The portal's booking is named once, as a booking, not again as its lease.
    assert [(p.code, p.message.split(" ")[0]) for p in check.problems] == [
        ("booked", "node-06"),
        ("lease", "node-05"),
    ]
    assert "“just-now”" in check.problems[1].message
    assert not SchedulerLease.objects.filter(name="just-now").exists()  # a check writes nothing
    # Booking says the same first problem.
    with pytest.raises(Conflict) as refused:
        without_run.reservation_create(
            owner=owner, resources=_nodes(5, 6), start_at=slot[0], end_at=slot[1]
        )
    assert refused.value.message == check.problems[0].message


def test_when_the_scheduler_cannot_be_reached_the_check_reads_the_mirror_and_says_so(
    linked, owner, slot, client_for
):
    linked.seed(
        name="fit-session",
        valid_from=slot[0].isoformat(),
        valid_until=slot[1].isoformat(),
        components=[{"name": "node-02"}],
        account_attributes={"name": "fit"},
    )
    leases.scheduler_sweep()  # mirrored
    linked.faults(unavailable=True)
    try:
        response = client_for(owner).post(
            "/api/v1/reservations/check/",
            {
                "resources": ["node-02"],
                "start_at": slot[0].isoformat(),
                "end_at": slot[1].isoformat(),
            },
            format="json",
        )
    finally:
        linked.faults(unavailable=False)
    assert response.status_code == 200, response.content
    body = response.json()
    assert [p["code"] for p in body["problems"]] == ["lease"]
    assert body["leases_from"] == "mirror"
    synced = SchedulerLink.objects.get(pk=1).last_success_at
    assert body["notice"] == (
        "The testbed scheduler did not answer: its leases are shown as of "
        f"{timezone.localtime(synced):%Y-%m-%d %H:%M}. Booking asks it again."
    )


def test_a_late_lease_over_a_booking_is_flagged_and_its_owner_and_the_admins_told(
    linked, owner, admin_user, slot, eager_tasks, django_capture_on_commit_callbacks
):
    with django_capture_on_commit_callbacks(execute=True):
        reservation = without_run.reservation_create(
            owner=owner, resources=_nodes(3), start_at=slot[0], end_at=slot[1]
        )
    mail.outbox.clear()
    # Someone wrote into the scheduler around its own rules.
    linked.seed(
        name="sneaky",
        valid_from=slot[0].isoformat(),
        valid_until=slot[1].isoformat(),
        components=[{"name": "node-03"}],
        account_attributes={"name": "elsewhere"},
    )
    with django_capture_on_commit_callbacks(execute=True):
        scheduler_sweep.delay()
    reservation.refresh_from_db()
    assert "“sneaky” (elsewhere), holds node-03" in reservation.conflict
    [message] = mail.outbox
    assert message.subject.startswith("A lease on the testbed scheduler overlaps a booking")
    assert set(message.to) == {owner.email, admin_user.email}
    with django_capture_on_commit_callbacks(execute=True):
        scheduler_sweep.delay()  # told once, not at every sweep
    assert len(mail.outbox) == 1


def test_a_booking_whose_lease_vanished_is_flagged(
    linked, owner, slot, eager_tasks, django_capture_on_commit_callbacks
):
    reservation = without_run.reservation_create(
        owner=owner, resources=_nodes(2), start_at=slot[0], end_at=slot[1]
    )
    with linked.scheduler() as scheduler:
        scheduler.cancel_lease(uuid=reservation.lease_uuid)
    with django_capture_on_commit_callbacks(execute=True):
        scheduler_sweep.delay()
    reservation.refresh_from_db()
    assert reservation.conflict.startswith("Its lease on the testbed scheduler is gone")
    assert mail.outbox[-1].subject.startswith("A booking lost its lease")


def test_a_sweep_whose_listing_is_older_than_a_booking_does_not_call_its_lease_gone(
    linked, owner, slot, eager_tasks, monkeypatch
):
    """The sweep asks for the scheduler's leases, a booking takes its lease and commits, and
    then the sweep reconciles with the listing it had: the booking's lease is missing from
    it, but recorded by a newer look, so it is not gone."""
    began = timezone.now()
    with linked.scheduler() as scheduler:
        before = scheduler.list_leases(statuses=leases.ALL_STATUSES)
    reservation = without_run.reservation_create(
        owner=owner, resources=_nodes(2), start_at=slot[0], end_at=slot[1]
    )
    assert reservation.lease_uuid not in {lease.uuid for lease in before}
    real_list = type(scheduler).list_leases
    monkeypatch.setattr(type(scheduler), "list_leases", lambda self, **kwargs: before)
    leases.scheduler_sweep(now=began)
    reservation.refresh_from_db()
    assert reservation.conflict == ""
    # The next sweep lists it, and a lease really gone is still flagged.
    monkeypatch.setattr(type(scheduler), "list_leases", real_list)
    with linked.scheduler() as scheduler:
        scheduler.cancel_lease(uuid=reservation.lease_uuid)
    leases.scheduler_sweep()
    reservation.refresh_from_db()
    assert reservation.conflict.startswith("Its lease on the testbed scheduler is gone")


def test_moving_a_booking_moves_its_lease_or_changes_neither(linked, owner, other, slot):
    reservation = without_run.reservation_create(
        owner=owner, resources=_nodes(1, 2), start_at=slot[0], end_at=slot[1]
    )
    later = (slot[0] + timedelta(hours=2), slot[1] + timedelta(hours=2))
    reservation_reschedule(reservation=reservation, by=owner, start_at=later[0], end_at=later[1])
    [lease] = _live(linked)
    assert (lease.valid_from, lease.valid_until) == later
    without_run.reservation_create(
        owner=other, resources=_nodes(2), start_at=slot[0], end_at=slot[1]
    )
    with pytest.raises(Conflict):
        reservation_reschedule(reservation=reservation, by=owner, start_at=slot[0], end_at=slot[1])
    reservation.refresh_from_db()
    assert (reservation.start_at, reservation.end_at) == later
    ours = next(lease for lease in _live(linked) if lease.uuid == reservation.lease_uuid)
    assert (ours.valid_from, ours.valid_until) == later


def test_cancelling_a_booking_cancels_its_lease(
    linked, owner, slot, eager_tasks, django_capture_on_commit_callbacks
):
    reservation = without_run.reservation_create(
        owner=owner, resources=_nodes(1), start_at=slot[0], end_at=slot[1]
    )
    with django_capture_on_commit_callbacks(execute=True):
        reservation_cancel(reservation=reservation, by=owner)
    assert _live(linked) == []


def test_a_booking_awaiting_approval_holds_its_lease_until_rejected(
    linked, owner, admin_user, slot, eager_tasks, django_capture_on_commit_callbacks
):
    [node] = _nodes(6)
    node.requires_approval = True
    node.save()
    reservation = without_run.reservation_create(
        owner=owner, resources=[node], start_at=slot[0], end_at=slot[1]
    )
    assert reservation.state == ReservationState.REQUESTED
    assert len(_live(linked)) == 1  # the slot is held while an admin decides
    with django_capture_on_commit_callbacks(execute=True):
        reservation_decide(
            reservation=reservation, by=admin_user, approve=False, reason="roof closed"
        )
    assert _live(linked) == []


def test_the_link_status_and_the_admins_page(linked, admin_user, client, slot):
    assert leases.scheduler_link_status()["ok"] is False  # never synced yet
    leases.scheduler_sweep()
    status = leases.scheduler_link_status()
    assert status["ok"] is True
    assert status["last_sync_age_s"] is not None
    health = client.get("/healthz").json()
    assert health["testbed_scheduler"]["ok"] is True
    linked.faults(unavailable=True)
    leases.scheduler_sweep()
    linked.faults(unavailable=False)
    sign_in_with_second_factor(client, admin_user)
    page = client.get("/scheduler-link/")
    assert page.status_code == 200
    link = SchedulerLink.objects.get()
    assert link.last_error
    assert link.last_error in page.content.decode()
    assert leases.scheduler_link_status()["last_error"] == link.last_error


def test_the_fixed_nodes_come_from_the_scheduler(linked):
    names = fixed_node_names_from_scheduler()
    assert names[:2] == ("node-01", "node-02")
    assert len(names) == 24


def test_only_admins_and_the_scheduler_account_book_for_others(linked, owner, other, slot):
    with pytest.raises(NotAllowed):
        without_run.reservation_create(
            owner=owner, by=other, resources=_nodes(1), start_at=slot[0], end_at=slot[1]
        )
    assert _live(linked) == []


def test_the_sweep_twice_cancels_an_orphan_and_tells_an_owner_once(
    linked, owner, slot, eager_tasks, django_capture_on_commit_callbacks
):
    with django_capture_on_commit_callbacks(execute=True):
        booked = without_run.reservation_create(
            owner=owner, resources=_nodes(2), start_at=slot[0], end_at=slot[1]
        )
    linked.seed(
        name="sneaky",
        valid_from=slot[0].isoformat(),
        valid_until=slot[1].isoformat(),
        components=[{"name": "node-02"}],
        account_attributes={"name": "elsewhere"},
    )
    with linked.scheduler() as scheduler:
        scheduler.create_lease(
            name=leases.lease_name_for(uuid.uuid4()),
            valid_from=slot[0],
            valid_until=slot[1],
            component_names=["node-05"],
        )
    mail.outbox.clear()
    with django_capture_on_commit_callbacks(execute=True):
        twice(scheduler_sweep)
    assert SchedulerLink.objects.get().orphans_cancelled == 1
    assert len(mail.outbox) == 1
    booked.refresh_from_db()
    assert "sneaky" in booked.conflict


def test_cancelling_a_lease_twice_cancels_it_once(linked, owner, slot):
    reservation = without_run.reservation_create(
        owner=owner, resources=_nodes(1), start_at=slot[0], end_at=slot[1]
    )
    twice(lease_cancel, reservation.lease_uuid)
    [lease] = _broker_leases(linked)
    assert lease.status == LeaseStatus.CANCELLED


def test_the_link_coming_back_after_failing_is_one_event_for_staff(linked, settings):
    from core.events.models import Event
    from core.events.sequence import events_sequence

    reachable = settings.SCHEDULER
    settings.SCHEDULER = scheduler_config.from_env({"SCHEDULER_URL": "http://127.0.0.1:9"})
    assert leases.scheduler_sweep() is None
    settings.SCHEDULER = reachable
    assert leases.scheduler_sweep() is not None
    assert leases.scheduler_sweep() is not None  # up, and still up: said once
    events_sequence()
    assert [(e.type, e.owner_id) for e in Event.objects.order_by("position")] == [
        ("scheduler.link_down", None),
        ("scheduler.link_up", None),
    ]
