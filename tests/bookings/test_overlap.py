"""Half-open overlap, spelled once per language, and every spelling agreeing.

The Python predicate (``bookings/periods.py``), the portal's queries
(``PeriodQuerySet.overlapping``), PostgreSQL's own ``tstzrange(…, '[)') &&`` (the operator of
the exclusion constraint on reservation items, and the constraint itself), the booking
check's SQL (``core.sql.overlap``) and the agent's SQLite condition
(``basestation.store.overlap_condition``) must answer alike, touching ends above all: back to
back is no overlap.
"""

from __future__ import annotations

import sqlite3
from datetime import UTC, datetime, timedelta

import pytest
from django.db import IntegrityError, connection, transaction
from hypothesis import given, settings
from hypothesis import strategies as st

from basestation.store import overlap_condition
from bookings.choices import ResourceKind
from bookings.models import Blackout, Reservation, ReservationItem, Resource
from bookings.periods import clip, gaps, overlap_s, overlaps, within
from bookings.scheduler import Lease, LeaseStatus
from core import sql
from core.accounts.models import User

BASE = datetime(2026, 12, 1, 10, 0, tzinfo=UTC)
# A coarse grid of minutes, so that random periods often touch end to start.
GRID_MINUTES = 10


def at(minute: int) -> datetime:
    return BASE + timedelta(minutes=minute)


# A period of the grid, never empty (the models' check constraints refuse empty ones).
periods = st.integers(0, GRID_MINUTES - 1).flatmap(
    lambda start: st.tuples(st.just(start), st.integers(start + 1, GRID_MINUTES))
)


@st.composite
def windows(draw: st.DrawFn) -> tuple[int | None, int | None]:
    """A query window; None leaves it open on that side, as a list filter given one end."""
    start = draw(st.none() | st.integers(0, GRID_MINUTES - 1))
    end = draw(st.none() | st.integers(0 if start is None else start + 1, GRID_MINUTES))
    return start, end


def _instant(minute: int | None) -> datetime | None:
    return None if minute is None else at(minute)


def test_back_to_back_is_no_overlap() -> None:
    assert not overlaps(at(0), at(2), at(2), at(4))
    assert not overlaps(at(2), at(4), at(0), at(2))
    assert overlaps(at(0), at(3), at(2), at(4))
    assert overlaps(at(1), at(2), at(0), at(4))  # inside
    assert overlaps(at(0), at(2), None, None)
    assert not overlaps(at(0), at(2), at(2), None)
    assert not overlaps(at(0), at(2), None, at(0))
    assert within(at(0), at(0), at(2))
    assert not within(at(2), at(0), at(2))


def test_clipping_and_gaps_follow_the_same_rule() -> None:
    assert clip(at(0), at(5), at(2), at(8)) == (at(2), at(5))
    assert clip(at(0), at(2), at(2), at(8)) is None
    assert overlap_s(at(0), at(5), at(2), at(8)) == 180.0
    assert overlap_s(at(0), at(2), at(2), at(8)) == 0.0
    busy = [(at(6), at(12)), (at(-3), at(1)), (at(2), at(3)), (at(2), at(4))]
    assert gaps(busy, at(0), at(10)) == [(at(1), at(2)), (at(4), at(6))]
    assert gaps([(at(10), at(12))], at(0), at(10)) == [(at(0), at(10))]
    assert gaps([], at(0), at(10)) == [(at(0), at(10))]


def test_a_lease_overlaps_by_the_same_rule() -> None:
    lease = Lease("u", "n", at(2), at(4), LeaseStatus.ACCEPTED, "acct", ("node-01",))
    assert lease.overlaps(start=at(0), end=at(3))
    assert not lease.overlaps(start=at(4), end=at(6))
    assert not lease.overlaps(start=None, end=at(2))
    assert lease.overlaps(start=None, end=None)


@pytest.mark.django_db
@settings(max_examples=60, deadline=None)
@given(rows=st.lists(periods, min_size=1, max_size=6), window=windows())
def test_the_predicate_the_queryset_and_postgresql_agree(
    rows: list[tuple[int, int]], window: tuple[int | None, int | None]
) -> None:
    assert connection.vendor == "postgresql"
    window_start, window_end = (_instant(m) for m in window)
    with transaction.atomic():
        owner = User.objects.create(username="overlap")
        reservations = Reservation.objects.bulk_create(
            Reservation(owner=owner, start_at=at(s), end_at=at(e)) for s, e in rows
        )
        ids = [r.pk for r in reservations]
        by_predicate = {
            r.pk for r in reservations if overlaps(r.start_at, r.end_at, window_start, window_end)
        }
        by_queryset = set(
            Reservation.objects.filter(pk__in=ids)
            .overlapping(window_start, window_end)
            .values_list("pk", flat=True)
        )
        with connection.cursor() as cursor:
            cursor.execute(
                "SELECT id FROM bookings_reservation WHERE id = ANY(%s) AND "
                "tstzrange(start_at, end_at, '[)') && "
                "tstzrange(%s::timestamptz, %s::timestamptz, '[)')",
                [ids, window_start, window_end],
            )
            by_ranges = {row[0] for row in cursor.fetchall()}
        assert by_predicate == by_queryset == by_ranges
        if window_start is not None and window_end is not None:
            # The hand-written SQL's condition (``bookings/queries.py``), closed windows only.
            with connection.cursor() as cursor:
                condition = sql.overlap("r")
                cursor.execute(
                    f"SELECT id FROM bookings_reservation r WHERE id = ANY(%s) AND {condition}",  # noqa: S608
                    [ids, window_end, window_start],
                )
                assert {row[0] for row in cursor.fetchall()} == by_predicate
        transaction.set_rollback(True)


@pytest.mark.django_db
@settings(max_examples=40, deadline=None)
@given(held=periods, asked=st.lists(periods, min_size=1, max_size=5))
def test_the_exclusion_constraint_refuses_exactly_what_overlaps(
    held: tuple[int, int], asked: list[tuple[int, int]]
) -> None:
    assert connection.vendor == "postgresql"
    with transaction.atomic():
        owner = User.objects.create(username="overlap")
        node = Resource.objects.create(name="node-overlap", kind=ResourceKind.FIXED)
        first = Reservation.objects.create(owner=owner, start_at=at(held[0]), end_at=at(held[1]))
        ReservationItem.objects.create(
            reservation=first, resource=node, start_at=first.start_at, end_at=first.end_at
        )
        for start, end in asked:
            other = Reservation.objects.create(owner=owner, start_at=at(start), end_at=at(end))
            item = ReservationItem(
                reservation=other, resource=node, start_at=at(start), end_at=at(end)
            )
            if overlaps(first.start_at, first.end_at, item.start_at, item.end_at):
                with (
                    pytest.raises(IntegrityError, match="reservation_item_no_overlap"),
                    transaction.atomic(),
                ):
                    item.save()
            else:
                with transaction.atomic():
                    item.save()
                    transaction.set_rollback(True)  # only the held period stays
        transaction.set_rollback(True)


@pytest.mark.django_db
@pytest.mark.parametrize(
    ("url", "make"),
    [
        (
            "/api/v1/reservations/",
            lambda owner, s, e: Reservation.objects.create(owner=owner, start_at=s, end_at=e),
        ),
        (
            "/api/v1/blackouts/",
            lambda owner, s, e: Blackout.objects.create(start_at=s, end_at=e, reason="works"),
        ),
    ],
)
def test_the_list_filters_leave_out_what_only_touches_the_window(
    url, make, admin_user, client_for
) -> None:
    ids = {
        name: make(admin_user, at(s), at(e)).pk
        for name, (s, e) in {"before": (0, 2), "inside": (3, 4), "after": (6, 8)}.items()
    }
    client = client_for(admin_user)

    def listed(**window: datetime) -> set[str]:
        response = client.get(url, {k: v.isoformat() for k, v in window.items()})
        assert response.status_code == 200, response.content
        found = {row["id"] for row in response.json()["results"]}
        return {name for name, pk in ids.items() if pk in found}

    assert listed(start=at(2), end=at(6)) == {"inside"}
    assert listed(start=at(1), end=at(7)) == {"before", "inside", "after"}
    assert listed(start=at(4)) == {"after"}
    assert listed(end=at(3)) == {"before"}


@settings(max_examples=100, deadline=None)
@given(
    rows=st.lists(periods | st.tuples(st.integers(0, GRID_MINUTES), st.none())),
    window=periods,
)
def test_the_agent_sql_agrees_with_the_predicate(
    rows: list[tuple[int, int | None]], window: tuple[int, int]
) -> None:
    """The agent's condition on SQLite, a NULL end (still running) open to the right."""
    db = sqlite3.connect(":memory:")
    try:
        db.execute("CREATE TABLE periods (id INTEGER PRIMARY KEY, started_at REAL, ended_at REAL)")
        db.executemany(
            "INSERT INTO periods (id, started_at, ended_at) VALUES (?, ?, ?)",
            [(i, float(s), None if e is None else float(e)) for i, (s, e) in enumerate(rows)],
        )
        for open_end in (False, True):
            condition, params = overlap_condition(
                "started_at", "ended_at", float(window[0]), float(window[1]), open_end=open_end
            )
            found = {
                row[0]
                for row in db.execute(f"SELECT id FROM periods WHERE {condition}", params)  # noqa: S608
            }
            expected = {
                i
                for i, (s, e) in enumerate(rows)
                if (e is not None or open_end)
                and overlaps(at(s), _instant(e), at(window[0]), at(window[1]))
            }
            assert found == expected, open_end
    finally:
        db.close()


def test_the_agent_sql_takes_only_column_names() -> None:
    with pytest.raises(ValueError, match="not a column name"):
        overlap_condition("start_at; DROP TABLE runs", "end_at", 0.0, 1.0)
