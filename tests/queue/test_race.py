"""Two allocators at once (PostgreSQL, real transactions): each request is booked once, and no
two bookings share the robot; the booking's lock and constraint, and the request held while it
is booked, do it (``portal/queue/allocation.py``). The passes race without their turn
(``allocation_pass``), so that those guards alone are what is tested; with it
(``queue_allocate``) they take turns and the slots go out in fair-share order."""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable
from datetime import UTC, datetime, timedelta

import pytest
from django.db import connection

from bookings.models import ReservationItem, Resource
from portal.queue.allocation import Pass, allocation_pass, queue_allocate
from portal.queue.models import QueueRequest, RequestState
from portal.queue.services import queue_request_submit
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory

pytestmark = pytest.mark.django_db(transaction=True)

NOW = datetime(2030, 1, 7, 9, 0, tzinfo=UTC)


def _three_people_three_requests_each() -> Resource:
    robot = MobileResourceFactory()
    for name in ("ana", "ben", "cai"):
        user = UserFactory(username=name)
        for _ in range(3):
            queue_request_submit(
                owner=user,
                experiment=ExperimentFactory(owner=user),
                robot=robot,
                duration_s=600,
                latest_end_at=NOW + timedelta(days=1),
                now=NOW,
            )
    return robot


def _at_once(allocate: Callable[..., Pass]) -> list[Pass]:
    """Two passes started together, each in a thread with its own connection."""
    start = threading.Barrier(2)
    passes: list[Pass] = []
    failures: list[BaseException] = []

    def allocator() -> None:
        try:
            start.wait(timeout=30)
            passes.append(allocate(now=NOW))
        except BaseException as exc:
            failures.append(exc)
        finally:
            connection.close()

    threads = [threading.Thread(target=allocator) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=120)
    assert not any(t.is_alive() for t in threads), "an allocator hung"
    assert not failures, failures
    return passes


def test_two_allocators_racing_book_each_request_once_and_never_one_slot_twice(settings):
    assert connection.vendor == "postgresql"
    settings.QUEUE_LEAD_S = 0
    robot = _three_people_three_requests_each()
    passes = _at_once(allocation_pass)

    booked = [pk for done in passes for pk in done.booked]
    assert sorted(booked) == sorted(set(booked)), "a request was booked twice"
    # A request one allocator held while the other took the slots it looked at may be left
    # for the next pass (it says why); the next pass books it, and nothing twice.
    booked += queue_allocate(now=NOW).booked
    assert sorted(booked) == sorted(set(booked)), "a request was booked twice"
    assert len(booked) == 9
    assert QueueRequest.objects.filter(state=RequestState.BOOKED).count() == 9
    items = sorted(
        ReservationItem.objects.filter(resource=robot, active=True).values_list(
            "start_at", "end_at"
        )
    )
    assert len(items) == 9
    for (_, end), (next_start, _) in itertools.pairwise(items):
        assert end <= next_start, "two bookings share the robot"


def test_two_passes_woken_at_once_take_turns_and_keep_the_fair_share_order(settings):
    settings.QUEUE_LEAD_S = 0
    _three_people_three_requests_each()
    passes = _at_once(queue_allocate)
    # The first books all nine; the second, after it, finds none waiting.
    assert sorted(len(done.booked) for done in passes) == [0, 9]
    booked = QueueRequest.objects.order_by("reservation__start_at")
    # Equal use each time round: who asked first; so one request of each person in turn.
    people = [r.owner.username for r in booked.select_related("owner")]
    assert people == ["ana", "ben", "cai"] * 3
