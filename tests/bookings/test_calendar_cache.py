"""The calendar's cached answers are scoped (``bookings/models.py``, ``core/cache.py``): a
booking moves on only the generations of the weeks, resources and user it touched, and no
answer is ever served stale, whatever is booked, moved or cancelled where."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
from django.db import connection, transaction
from django.test import override_settings
from django.utils import timezone
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rest_framework.test import APIClient

from bookings.models import (
    CALENDAR,
    CALENDAR_SETUP,
    Blackout,
    Reservation,
    ReservationItem,
    SchedulerLease,
    bookings_in_week,
    bookings_of,
    busy_generations,
    calendar_weeks,
    leases_in_week,
    resource_in_week,
)
from bookings.selectors import busy_slots
from bookings.services import reservation_cancel, reservation_create, reservation_reschedule
from core.cache import Generation, cached_answer
from core.errors import DomainError
from tests.factories import FixedResourceFactory, UserFactory

pytestmark = pytest.mark.django_db(transaction=True)

_NO_CACHE = {"default": {"BACKEND": "django.core.cache.backends.dummy.DummyCache"}}


def _next_monday() -> datetime:
    """00:00 UTC of the Monday after next: far enough for every notice, inside the advance."""
    today = timezone.now().astimezone(UTC).replace(hour=0, minute=0, second=0, microsecond=0)
    return today + timedelta(days=7 - today.weekday() + 7)


def _moved(generations: list[Generation], change: Callable[[], object]) -> set[str]:
    before = {g.name: g.current() for g in generations}
    change()
    return {g.name for g in generations if g.current() != before[g.name]}


def test_a_booking_moves_only_its_weeks_resources_and_owner():
    node, other_node = FixedResourceFactory(), FixedResourceFactory()
    owner, someone = UserFactory(), UserFactory()
    monday = _next_monday()
    start = monday + timedelta(days=2, hours=10)
    (week,) = calendar_weeks(start, start + timedelta(hours=1))
    watched = [
        CALENDAR,
        CALENDAR_SETUP,
        bookings_in_week(week),
        bookings_in_week(week + 1),
        resource_in_week(node.pk, week),
        resource_in_week(node.pk, week + 1),
        resource_in_week(other_node.pk, week),
        leases_in_week(week),
        bookings_of(owner.pk),
        bookings_of(someone.pk),
    ]

    booked: list[Reservation] = []
    moved = _moved(
        watched,
        lambda: booked.append(
            reservation_create(
                owner=owner, resource=node, start_at=start, end_at=start + timedelta(hours=1)
            )
        ),
    )
    assert moved == {
        "calendar",
        f"calendar:week:{week}",
        f"calendar:resource:{node.pk}:week:{week}",
        f"calendar:user:{owner.pk}",
    }

    later = start + timedelta(weeks=1)
    moved = _moved(
        watched,
        lambda: reservation_reschedule(
            reservation=booked[0], by=owner, start_at=later, end_at=later + timedelta(hours=1)
        ),
    )
    assert moved == {
        "calendar",
        f"calendar:week:{week}",
        f"calendar:week:{week + 1}",
        f"calendar:resource:{node.pk}:week:{week}",
        f"calendar:resource:{node.pk}:week:{week + 1}",
        f"calendar:user:{owner.pk}",
    }, "a move retires where the booking was and where it is"

    moved = _moved(
        watched,
        lambda: reservation_cancel(reservation=Reservation.objects.get(), by=owner),
    )
    assert moved == {
        "calendar",
        f"calendar:week:{week + 1}",
        f"calendar:resource:{node.pk}:week:{week + 1}",
        f"calendar:user:{owner.pk}",
    }

    moved = _moved(
        watched,
        lambda: SchedulerLease.objects.create(
            uuid="lease-1",
            name="elsewhere",
            start_at=start,
            end_at=start + timedelta(hours=2),
            status="accepted",
            holds=True,
            seen_at=timezone.now(),
        ),
    )
    assert moved == {"calendar", f"calendar:week:{week}", f"calendar:leases:week:{week}"}

    moved = _moved(
        watched,
        lambda: Blackout.objects.create(
            start_at=start, end_at=start + timedelta(hours=1), reason="roof works"
        ),
    )
    assert moved == {"calendar", "calendar:setup"}


def test_each_bulk_write_moves_the_rows_it_wrote_before_and_after():
    node = FixedResourceFactory()
    owner = UserFactory()
    start = _next_monday() + timedelta(hours=9)
    (week,) = calendar_weeks(start, start + timedelta(hours=1))
    reservation = Reservation.objects.create(
        owner=owner, start_at=start, end_at=start + timedelta(hours=1)
    )
    item = ReservationItem(
        reservation=reservation, resource=node, start_at=start, end_at=start + timedelta(hours=1)
    )
    here = resource_in_week(node.pk, week)
    there = resource_in_week(node.pk, week + 2)
    watched = [here, there, bookings_of(owner.pk), CALENDAR_SETUP]

    assert _moved(watched, lambda: ReservationItem.objects.bulk_create([item])) == {
        here.name,
        f"calendar:user:{owner.pk}",
    }
    later = start + timedelta(weeks=2)
    moved = _moved(
        watched,
        lambda: reservation.items.update(start_at=later, end_at=later + timedelta(hours=1)),
    )
    assert moved == {here.name, there.name, f"calendar:user:{owner.pk}"}
    item.refresh_from_db()
    item.start_at, item.end_at = start, start + timedelta(hours=1)
    moved = _moved(
        watched, lambda: ReservationItem.objects.bulk_update([item], ["start_at", "end_at"])
    )
    assert moved == {here.name, there.name, f"calendar:user:{owner.pk}"}
    assert _moved(watched, lambda: reservation.items.update(active=False)) == {
        here.name,
        f"calendar:user:{owner.pk}",
    }
    assert _moved(watched, lambda: ReservationItem.objects.filter(pk=-1).update(active=True)) == (
        set()
    ), "a write that changes no row moves nothing"
    assert _moved(watched, lambda: reservation.delete()) == {here.name, f"calendar:user:{owner.pk}"}


def test_a_rolled_back_savepoint_leaves_no_change_unannounced():
    """The batch a transaction moves at its commit survives a savepoint rolled back after it
    began, and one begun in that savepoint is begun again by the next change."""
    node = FixedResourceFactory()
    owner = UserFactory()
    start = _next_monday() + timedelta(hours=9)
    (week,) = calendar_weeks(start, start + timedelta(hours=1))
    here = resource_in_week(node.pk, week)
    before = here.current()
    with transaction.atomic():
        try:
            with transaction.atomic():
                Reservation.objects.create(
                    owner=owner, start_at=start, end_at=start + timedelta(hours=1)
                )
                raise RuntimeError("rolled back")
        except RuntimeError:
            pass
        reservation = Reservation.objects.create(
            owner=owner, start_at=start, end_at=start + timedelta(hours=1)
        )
        ReservationItem.objects.create(
            reservation=reservation, resource=node, start_at=start,
            end_at=start + timedelta(hours=1),
        )  # fmt: skip
        assert here.pending()
        assert here.current() == before
    assert here.current() != before


def test_a_busy_week_read_while_a_booking_commits_is_not_kept():
    """A reader between a booking and its commit sees the week before it; what it stores is
    left behind when the booking commits."""
    node = FixedResourceFactory()
    owner = UserFactory()
    monday = _next_monday()
    week_end = monday + timedelta(weeks=1)
    generations = busy_generations(monday, week_end)
    seen: list[int] = []

    def busy() -> int:
        return len(busy_slots(start_at=monday, end_at=week_end))

    def reader() -> None:
        try:
            seen.append(cached_answer(generations, ("busy",), busy))
        finally:
            connection.close()

    assert cached_answer(generations, ("busy",), busy) == 0
    start = monday + timedelta(days=1, hours=9)
    with transaction.atomic():
        reservation_create(
            owner=owner, resource=node, start_at=start, end_at=start + timedelta(hours=1)
        )
        other = threading.Thread(target=reader)
        other.start()
        other.join()
        assert cached_answer(generations, ("busy",), busy) == 1, "its own change, read past"
    assert seen == [0], "the other connection read before the commit"
    assert cached_answer(generations, ("busy",), busy) == 1


# --- Every cached answer equals the uncached one, whatever happens where ---------------------

_HOURS = st.integers(min_value=0, max_value=3 * 7 * 24 - 3)
_OPERATION = st.one_of(
    st.tuples(
        st.just("book"),
        st.integers(0, 1),  # user
        st.lists(st.integers(0, 2), min_size=1, max_size=2, unique=True),  # resources
        _HOURS,
        st.integers(1, 2),  # hours long
    ),
    st.tuples(st.just("move"), st.integers(0, 5), _HOURS),
    st.tuples(st.just("cancel"), st.integers(0, 5)),
)


@contextmanager
def _uncached() -> Iterator[None]:
    with override_settings(CACHES=_NO_CACHE):
        yield


@pytest.fixture
def calendar_world():
    nodes = [FixedResourceFactory() for _ in range(3)]
    users = [UserFactory() for _ in range(2)]
    clients = []
    for user in users:
        client = APIClient()
        client.force_authenticate(user)
        clients.append(client)
    return nodes, users, clients


def _queries(nodes: list[Any], monday: datetime) -> tuple[list[str], list[str]]:
    """What everyone sees alike (asked by one user), and what each user sees of their own."""

    def span(first: int, weeks: int) -> str:
        start = monday + timedelta(weeks=first)
        end = start + timedelta(weeks=weeks)
        return f"start={start.isoformat()}&end={end.isoformat()}".replace("+", "%2B")

    shared = [
        *(f"/api/v1/reservations/busy/?{span(w, 1)}" for w in range(3)),
        f"/api/v1/reservations/busy/?{span(0, 3)}",
        *(
            f"/api/v1/resources/{node.name}/availability/?{span(w, 1)}"
            for node in nodes
            for w in (0, 2)
        ),
    ]
    return shared, ["/api/v1/quota/", "/api/v1/reservations/"]


@settings(
    max_examples=8,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(operations=st.lists(_OPERATION, min_size=1, max_size=5))
def test_every_cached_answer_equals_the_uncached_one_after_each_change(calendar_world, operations):
    nodes, users, clients = calendar_world
    Reservation.objects.all().delete()  # what an earlier example booked
    monday = _next_monday()
    shared, own = _queries(nodes, monday)
    asked = [(clients[0], url) for url in shared] + [(c, url) for c in clients for url in own]
    booked: list[Reservation] = []

    def check(step: str) -> None:
        for client, url in asked:
            cached = client.get(url)
            with _uncached():
                fresh = client.get(url)
            assert cached.status_code == fresh.status_code == 200, (url, cached.content)
            assert cached.json() == fresh.json(), f"{url} after {step}"

    check("nothing")  # every answer in the cache before the first change
    for operation in operations:
        try:
            if operation[0] == "book":
                _, who, which, hour, hours = operation
                start = monday + timedelta(hours=hour)
                booked.append(
                    reservation_create(
                        owner=users[who],
                        resources=[nodes[i] for i in which],
                        start_at=start,
                        end_at=start + timedelta(hours=hours),
                    )
                )
            elif booked and operation[0] == "move":
                reservation = Reservation.objects.get(pk=booked[operation[1] % len(booked)].pk)
                start = monday + timedelta(hours=operation[2])
                reservation_reschedule(
                    reservation=reservation,
                    by=reservation.owner,
                    start_at=start,
                    end_at=start + (reservation.end_at - reservation.start_at),
                )
            elif booked and operation[0] == "cancel":
                reservation = Reservation.objects.get(pk=booked[operation[1] % len(booked)].pk)
                reservation_cancel(reservation=reservation, by=reservation.owner)
        except DomainError:
            pass  # refused (taken, cancelled already): nothing changed, still checked
        check(repr(operation))
