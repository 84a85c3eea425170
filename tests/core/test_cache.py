"""Cached answers and the generations that retire them (``core/cache.py``), and the calendar's
answers (resources, busy slots, availability) that use them."""

from __future__ import annotations

import threading
import time
from datetime import timedelta

import pytest
from django.db import connection, transaction
from django.utils import timezone

from bookings.models import (
    CALENDAR,
    CALENDAR_SETUP,
    Blackout,
    QuotaPolicy,
    Reservation,
    ReservationItem,
    Resource,
    ResourceGroup,
    SchedulerLease,
)
from bookings.rules import QuotaExceeded
from bookings.services import reservation_create
from core.cache import ChangeTrackedQuerySet, Generation, cached_answer
from tests.factories import FixedResourceFactory, MobileResourceFactory, UserFactory

pytestmark = pytest.mark.django_db


class Counted:
    """A computation that says how often it ran."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self) -> int:
        self.calls += 1
        return self.calls


def test_an_answer_is_computed_once_per_generation_and_parts():
    generation = Generation("test-once")
    compute = Counted()
    assert generation.answer(("a",), compute) == 1
    assert generation.answer(("a",), compute) == 1
    assert generation.answer(("b",), compute) == 2
    generation.changed()
    assert generation.answer(("a",), compute) == 3


def test_an_answer_of_several_generations_is_retired_by_any_of_them():
    first, second = Generation("test-first"), Generation("test-second")
    compute = Counted()
    assert cached_answer((first, second), ("a",), compute) == 1
    assert cached_answer((first, second), ("a",), compute) == 1
    second.changed()
    assert cached_answer((first, second), ("a",), compute) == 2
    first.changed()
    assert cached_answer((first, second), ("a",), compute) == 3
    assert cached_answer((first,), ("a",), compute) == 4, "another family of answers"


def test_a_kept_answer_costs_one_cache_round_trip(monkeypatch):
    from django.core.cache import cache

    first, second = Generation("test-trips-1"), Generation("test-trips-2")
    cached_answer((first, second), ("a",), Counted())
    calls: list[str] = []
    for method in ("get", "get_many", "set", "add", "incr"):
        original = getattr(cache, method)
        monkeypatch.setattr(
            cache,
            method,
            lambda *a, _m=method, _o=original, **k: calls.append(_m) or _o(*a, **k),
        )
    assert cached_answer((first, second), ("a",), Counted()) == 1
    assert calls == ["get_many"]


def test_a_flushed_cache_starts_a_generation_no_earlier_one_used(settings):
    from django.core.cache import cache

    generation = Generation("test-flush")
    before = generation.current()
    cache.clear()
    assert generation.current() > before


def test_the_calendar_follows_every_model_its_answers_read():
    setup = {
        model
        for model in (Resource, ResourceGroup, Blackout, QuotaPolicy)
        if CALENDAR_SETUP in getattr(model, "_generations", ())
        and CALENDAR in getattr(model, "_generations", ())
    }
    assert setup == {Resource, ResourceGroup, Blackout, QuotaPolicy}
    scoped = {
        model
        for model in (Reservation, ReservationItem, SchedulerLease)
        if getattr(model, "_cache_scope", None) is not None
    }
    assert scoped == {Reservation, ReservationItem, SchedulerLease}
    for model in setup | scoped:
        assert isinstance(model.objects.all(), ChangeTrackedQuerySet)


def _moves_the_calendar(change) -> bool:
    before = CALENDAR.current()
    change()
    return CALENDAR.current() != before


@pytest.mark.django_db(transaction=True)
def test_every_kind_of_write_moves_the_calendar_on():
    robot = MobileResourceFactory()
    node = FixedResourceFactory()
    group = ResourceGroup.objects.create(name="north")
    owner = UserFactory()
    start = timezone.now() + timedelta(days=1)
    end = start + timedelta(hours=1)

    assert _moves_the_calendar(
        lambda: Resource.objects.filter(pk=robot.pk).update(hold_reason="e-stop")
    )
    assert _moves_the_calendar(lambda: robot.save())
    assert _moves_the_calendar(lambda: robot.groups.add(group))
    assert _moves_the_calendar(lambda: group.resources.remove(robot))
    reservation = Reservation(owner=owner, start_at=start, end_at=end)
    assert _moves_the_calendar(lambda: Reservation.objects.bulk_create([reservation]))
    item = ReservationItem(reservation=reservation, resource=node, start_at=start, end_at=end)
    assert _moves_the_calendar(lambda: item.save())
    item.active = False
    assert _moves_the_calendar(lambda: ReservationItem.objects.bulk_update([item], ["active"]))
    blackout = Blackout.objects.create(start_at=start, end_at=end, reason="roof works")
    assert _moves_the_calendar(lambda: blackout.resources.add(node))
    assert _moves_the_calendar(lambda: Blackout.objects.filter(pk=blackout.pk).delete())
    assert _moves_the_calendar(lambda: reservation.delete())
    # A write that changes no row moves nothing: the health sweep's idle checks stay cheap.
    assert not _moves_the_calendar(lambda: Resource.objects.filter(pk=-1).update(enabled=False))


@pytest.mark.django_db(transaction=True)
def test_an_answer_read_while_a_change_commits_is_not_kept():
    """A reader between the change and its commit sees the rows before it; what it stores is
    left behind when the transaction commits."""
    robot = MobileResourceFactory()
    seen: list[str] = []

    def read_hold() -> str:
        return str(Resource.objects.get(pk=robot.pk).hold_reason)

    def reader() -> None:
        try:
            seen.append(CALENDAR.answer(("hold", robot.pk), read_hold))
        finally:
            connection.close()

    with transaction.atomic():
        Resource.objects.filter(pk=robot.pk).update(hold_reason="e-stop")
        other = threading.Thread(target=reader)
        other.start()
        other.join()
    assert seen == [""], "the other connection read before the commit"
    assert CALENDAR.answer(("hold", robot.pk), read_hold) == "e-stop"


@pytest.mark.django_db(transaction=True)
def test_a_transaction_moves_the_generation_once_at_commit_and_reads_its_own_changes(
    monkeypatch,
):
    """A booking writes several rows: the calendar moves on once, when it commits; until
    then the transaction's own reads see its changes, and nobody keeps what they computed."""
    from django.core.cache import cache

    robot = MobileResourceFactory()
    node = FixedResourceFactory()
    bumps: list[list[str]] = []
    original = cache.incr_many_from

    def counted(keys: list[str], start: int) -> None:
        bumps.append(keys)
        original(keys, start)

    monkeypatch.setattr(cache, "incr_many_from", counted)

    def holds() -> list[str]:
        return sorted(Resource.objects.values_list("hold_reason", flat=True))

    before = CALENDAR.current()
    assert CALENDAR.answer(("holds",), holds) == ["", ""]
    with transaction.atomic():
        Resource.objects.filter(pk=robot.pk).update(hold_reason="e-stop")
        assert CALENDAR.answer(("holds",), holds) == ["", "e-stop"]
        Resource.objects.filter(pk=node.pk).update(hold_reason="roof works")
        robot.refresh_from_db()
        robot.save()
        assert CALENDAR.answer(("holds",), holds) == ["e-stop", "roof works"]
        assert bumps == []
        assert CALENDAR.current() == before
    assert len(bumps) == 1
    assert CALENDAR.current() != before
    assert CALENDAR.answer(("holds",), holds) == ["e-stop", "roof works"]
    with transaction.atomic():
        Resource.objects.filter(pk=node.pk).update(hold_reason="")
        transaction.set_rollback(True)
    assert len(bumps) == 1, "a rolled back change moves nothing"
    # A write outside a transaction moves it at once.
    Resource.objects.filter(pk=node.pk).update(hold_reason="")
    assert len(bumps) == 2


def test_a_generation_missing_from_the_cache_starts_again_from_the_clock():
    from django.core.cache import cache

    generation = Generation("test-missing")
    cache.delete(generation._key())
    started_ns = time.time_ns()
    generation.changed()
    assert generation.current() > started_ns


def _week() -> dict[str, str]:
    start = timezone.now().replace(microsecond=0) + timedelta(hours=1)
    return {"start": start.isoformat(), "end": (start + timedelta(days=7)).isoformat()}


def test_busy_slots_show_a_booking_made_after_they_were_read(api, mobile, experiment):
    week = _week()
    assert api.get("/api/v1/reservations/busy/", week).json() == []
    start = timezone.now().replace(microsecond=0) + timedelta(hours=2)
    booked = api.post(
        "/api/v1/reservations/",
        {
            "resource": mobile.name,
            "experiment": experiment.pk,
            "start_at": start.isoformat(),
            "end_at": (start + timedelta(minutes=30)).isoformat(),
        },
        format="json",
    )
    assert booked.status_code == 201, booked.content
    busy = api.get("/api/v1/reservations/busy/", week).json()
    assert [row["resources"] for row in busy] == [[mobile.name]]
    cancelled = api.delete(f"/api/v1/reservations/{booked.json()['id']}/")
    assert cancelled.status_code == 200, cancelled.content
    assert api.get("/api/v1/reservations/busy/", week).json() == []


def test_availability_and_resources_follow_a_hold_and_a_blackout(api, mobile):
    week = _week()
    url = f"/api/v1/resources/{mobile.name}/availability/"
    assert len(api.get(url, week).json()["free"]) == 1
    listed = {r["name"]: r for r in api.get("/api/v1/resources/").json()}
    assert listed[mobile.name]["hold_reason"] == ""

    Resource.objects.filter(pk=mobile.pk).update(hold_reason="e-stop latched")
    assert api.get(url, week).json()["free"] == []
    listed = {r["name"]: r for r in api.get("/api/v1/resources/").json()}
    assert listed[mobile.name]["hold_reason"] == "e-stop latched"

    Resource.objects.filter(pk=mobile.pk).update(hold_reason="")
    start = timezone.now() + timedelta(days=2)
    blackout = Blackout.objects.create(
        start_at=start, end_at=start + timedelta(hours=3), reason="roof works"
    )
    blackout.resources.add(mobile)
    assert len(api.get(url, week).json()["free"]) == 2


def test_availability_of_an_unknown_resource_is_404(api):
    assert api.get("/api/v1/resources/nowhere/availability/", _week()).status_code == 404


def test_the_redis_cache_keeps_one_client_per_pool_and_serves_threads():
    from django.core.cache import caches

    from core.redis_cache import RedisCache

    cache = caches["default"]
    assert isinstance(cache, RedisCache), "make test runs on Redis"
    client = cache._cache.get_client("a")
    assert cache._cache.get_client("b") is client
    seen: list[object] = []

    def use() -> None:
        cache.set(f"thread-{threading.get_ident()}", 1)
        seen.append(cache.get(f"thread-{threading.get_ident()}"))

    threads = [threading.Thread(target=use) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert seen == [1] * 8


@pytest.mark.django_db(transaction=True)
def test_the_next_booking_judges_by_a_policy_just_written():
    """The active quota policies are kept in the cache (``QUOTA_POLICIES``): a policy
    created, tightened or switched off is what the next booking is judged by."""
    node = FixedResourceFactory()
    owner = UserFactory()
    start = timezone.now() + timedelta(days=2)

    def book(hour: int) -> None:
        at = start + timedelta(hours=hour)
        reservation_create(owner=owner, resource=node, start_at=at, end_at=at + timedelta(hours=1))

    book(0)  # no policy yet: the empty list is what the cache keeps
    policy = QuotaPolicy.objects.create(name="one at a time", max_future=1)
    with pytest.raises(QuotaExceeded):
        book(2)
    policy.max_future = 2
    policy.save()
    book(2)
    QuotaPolicy.objects.filter(pk=policy.pk).update(active=False)
    book(4)
    assert Reservation.objects.filter(owner=owner).count() == 3
