"""Races over real HTTP against a threaded server on PostgreSQL: locks and constraint hold."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from datetime import timedelta

import pytest
import requests
from django.db import IntegrityError, transaction
from django.utils import timezone

from bookings.choices import QuotaPeriod, ReservationState
from bookings.models import QuotaPolicy, Reservation, ReservationItem
from tests.factories import FixedResourceFactory, UserFactory, api_token

pytestmark = [pytest.mark.long, pytest.mark.django_db(transaction=True)]


def _post_all(url: str, jobs: list[tuple[str, dict]]) -> list[requests.Response]:
    def post(job: tuple[str, dict]) -> requests.Response:
        token, body = job
        return requests.post(
            url, json=body, headers={"Authorization": f"Token {token}"}, timeout=60
        )

    with ThreadPoolExecutor(max_workers=len(jobs)) as pool:
        return list(pool.map(post, jobs))


def test_fifty_clients_racing_for_one_slot_get_exactly_one_booking(live_server):
    node = FixedResourceFactory(name="node-07")
    start = timezone.now() + timedelta(days=1)
    body = {
        "resource": node.name,
        "start_at": start.isoformat(),
        "end_at": (start + timedelta(hours=1)).isoformat(),
    }
    tokens = [api_token(UserFactory(username=f"racer{i}")) for i in range(50)]
    responses = _post_all(f"{live_server.url}/api/v1/reservations/", [(t, body) for t in tokens])
    codes = sorted(r.status_code for r in responses)
    assert codes == [201] + [409] * 49, codes
    for refused in (r for r in responses if r.status_code == 409):
        assert "node-07 is already booked from" in refused.json()["detail"]
    assert Reservation.objects.filter(state=ReservationState.CONFIRMED).count() == 1


def test_a_two_hour_weekly_quota_admits_exactly_two_of_twenty_concurrent_hours(live_server):
    user = UserFactory(username="quota")
    QuotaPolicy.objects.create(
        name="Two hours a week", user=user, period=QuotaPeriod.WEEK, max_hours=2
    )
    token = api_token(user)
    # Twenty different one-hour slots of twenty different nodes, all in next week.
    monday = timezone.localdate() + timedelta(days=7 - timezone.localdate().weekday())
    start = timezone.make_aware(timezone.datetime.combine(monday, timezone.datetime.min.time()))
    jobs = []
    for i in range(20):
        node = FixedResourceFactory(name=f"node-{i + 1:02d}")
        slot = start + timedelta(hours=8 + i)
        jobs.append(
            (
                token,
                {
                    "resource": node.name,
                    "start_at": slot.isoformat(),
                    "end_at": (slot + timedelta(hours=1)).isoformat(),
                },
            )
        )
    responses = _post_all(f"{live_server.url}/api/v1/reservations/", jobs)
    codes = sorted(r.status_code for r in responses)
    assert codes == [201] * 2 + [409] * 18, codes
    refused = next(r for r in responses if r.status_code == 409).json()
    assert refused["error"] == "quota_exceeded"
    assert "allows 2 h per week" in refused["detail"]
    assert Reservation.objects.filter(owner=user).count() == 2


def test_the_database_refuses_an_overlap_that_skips_the_services(owner):
    node = FixedResourceFactory()
    start = timezone.now() + timedelta(days=2)
    first = Reservation.objects.create(
        owner=owner, start_at=start, end_at=start + timedelta(hours=1)
    )
    ReservationItem.objects.create(
        reservation=first, resource=node, start_at=first.start_at, end_at=first.end_at
    )
    second = Reservation.objects.create(
        owner=owner, start_at=start + timedelta(minutes=30), end_at=start + timedelta(hours=2)
    )
    with pytest.raises(IntegrityError, match="reservation_item_no_overlap"), transaction.atomic():
        ReservationItem.objects.create(
            reservation=second, resource=node, start_at=second.start_at, end_at=second.end_at
        )
    # Inactive (cancelled) holdings do not block.
    ReservationItem.objects.create(
        reservation=second,
        resource=node,
        start_at=second.start_at,
        end_at=second.end_at,
        active=False,
    )
