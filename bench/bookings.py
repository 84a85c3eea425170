"""Booking against a full calendar, beside a trivial authenticated call, in the same run.

DESIGN §6: creating a reservation against 100 000 existing ones stays within twice the time
of a trivial authenticated API call. Both go through the whole Django stack (middleware,
token authentication, DRF, the service with its locks and checks, the database) with Django's test
client, so the ratio isolates what the booking itself costs. Also: a month's availability
of one resource.
"""

from __future__ import annotations

import io
import statistics
import time
from datetime import UTC, datetime, timedelta
from typing import Any

EXISTING = 100_000
CALLS = 200
BATCH = 5000


def _seed(existing: int) -> dict[str, Any]:

    from bookings.choices import QuotaPeriod, ResourceKind
    from bookings.models import QuotaPolicy, Reservation, ReservationItem, Resource
    from core.accounts.models import ApiToken, User

    owners = [User.objects.create_user(username=f"bench{i}") for i in range(50)]
    nodes = [
        Resource.objects.create(name=f"node-{i:02d}", kind=ResourceKind.FIXED) for i in range(1, 25)
    ]
    base = datetime.now(UTC).replace(minute=0, second=0, microsecond=0) + timedelta(days=1)
    # One-hour bookings, back to back on every node: a calendar as full as it gets.
    per_node = -(-existing // len(nodes))
    made = 0
    while made < existing:
        batch = []
        for k in range(made, min(made + BATCH, existing)):
            node_index, slot = divmod(k, per_node)
            start = base + timedelta(hours=slot)
            batch.append(
                (
                    Reservation(
                        owner=owners[k % len(owners)],
                        start_at=start,
                        end_at=start + timedelta(hours=1),
                    ),
                    nodes[node_index],
                )
            )
        Reservation.objects.bulk_create([r for r, _ in batch])
        ReservationItem.objects.bulk_create(
            ReservationItem(reservation=r, resource=n, start_at=r.start_at, end_at=r.end_at)
            for r, n in batch
        )
        made += len(batch)
    user = User.objects.create_user(username="booker")
    QuotaPolicy.objects.create(name="weekly", period=QuotaPeriod.WEEK, max_hours=10_000)
    return {
        "token": ApiToken.objects.create(user=user, name="bench")[1],
        "nodes": nodes,
        "base": base,
        "free_from": base + timedelta(hours=per_node + 24),
        "month": (base + timedelta(days=30), base + timedelta(days=61)),
    }


def _timed(fn: Any, calls: int) -> list[float]:
    samples = []
    for i in range(calls):
        t0 = time.perf_counter()
        fn(i)
        samples.append(time.perf_counter() - t0)
    return samples


def _interleaved(first: Any, second: Any, calls: int) -> tuple[list[float], list[float]]:
    a: list[float] = []
    b: list[float] = []
    for i in range(calls):
        a += _timed(lambda _j, i=i: first(i), 1)
        b += _timed(lambda _j, i=i: second(i), 1)
    return a, b


def _ms(samples: list[float]) -> str:
    ordered = sorted(samples)
    p95 = ordered[int(0.95 * (len(ordered) - 1))]
    return f"{statistics.median(samples) * 1000:.1f} ms (p95 {p95 * 1000:.1f} ms)"


def run(*, existing: int = EXISTING, calls: int = CALLS) -> str:
    from django.conf import settings
    from django.db import connection
    from django.test import Client

    settings.DEBUG = False  # no query log: measure what production runs
    settings.ALLOWED_HOSTS = ["testserver"]
    t0 = time.perf_counter()
    seed = _seed(existing)
    with connection.cursor() as cursor:
        cursor.execute("ANALYZE")
    seed_s = time.perf_counter() - t0
    client = Client(HTTP_AUTHORIZATION=f"Token {seed['token']}")
    nodes = seed["nodes"]

    def trivial(_i: int) -> None:
        assert client.get("/api/v1/resources/").status_code == 200

    def book(i: int) -> None:
        start = seed["free_from"] + timedelta(hours=2 * (i // len(nodes)))
        response = client.post(
            "/api/v1/reservations/",
            {
                "resource": nodes[i % len(nodes)].name,
                "start_at": start.isoformat(),
                "end_at": (start + timedelta(hours=1)).isoformat(),
            },
            content_type="application/json",
        )
        assert response.status_code == 201, response.content

    def refused(i: int) -> None:
        # An overlap, found among the 100 000 by the index and refused with 409.
        start = seed["base"] + timedelta(hours=10 + i)
        response = client.post(
            "/api/v1/reservations/",
            {
                "resource": nodes[0].name,
                "start_at": start.isoformat(),
                "end_at": (start + timedelta(minutes=30)).isoformat(),
            },
            content_type="application/json",
        )
        assert response.status_code in (400, 409), response.content

    month_start, month_end = seed["month"]

    def availability(_i: int) -> None:
        response = client.get(
            f"/api/v1/resources/{nodes[0].name}/availability/",
            {"start": month_start.isoformat(), "end": month_end.isoformat()},
        )
        assert response.status_code == 200

    for warm in (trivial, book):
        warm(10_000)
    # Interleaved, so both series see the same moments of a shared machine.
    trivial_s, book_s = _interleaved(trivial, book, calls)
    refused_s = _timed(refused, min(calls, 50))
    availability_s = _timed(availability, min(calls, 50))
    ratio = statistics.median(book_s) / statistics.median(trivial_s)
    out = io.StringIO()
    out.write("## Booking against a full calendar (PostgreSQL)\n\n")
    out.write(
        f"{existing:,} existing one-hour reservations on 24 nodes (seeded in {seed_s:.0f} s), "
        f"a quota policy in force; {calls} calls each through the whole Django stack with token "
        "authentication, median and 95th percentile.\n\n"
    )
    out.write("| call | time | vs. trivial | target |\n| --- | --- | --- | --- |\n")
    out.write(f"| `GET /api/v1/resources/` (trivial, authenticated) | {_ms(trivial_s)} | 1× | |\n")
    out.write(f"| `POST /api/v1/reservations/` (created) | {_ms(book_s)} | {ratio:.1f}× | ≤ 2× |\n")
    refused_ratio = statistics.median(refused_s) / statistics.median(trivial_s)
    out.write(
        f"| `POST /api/v1/reservations/` (overlap, 409) | {_ms(refused_s)} | "
        f"{refused_ratio:.1f}× | |\n"
    )
    month_ratio = statistics.median(availability_s) / statistics.median(trivial_s)
    out.write(
        f"| a month's availability of one node (~740 bookings in it) | {_ms(availability_s)} | "
        f"{month_ratio:.1f}× | |\n"
    )
    return out.getvalue()
