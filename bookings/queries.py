"""The bookings' hand-written SQL: what runs under the booking lock on every booking.

Each is SQL because building the same query through the ORM took longer than the database
took to answer it (docs/performance-history.md). Built from ``core.sql``'s helpers, module
constants and bound parameters only (``tests/test_architecture.py``); each runs on SQLite too
(``tests/test_queries_sqlite.py``). The rules that use them stay in ``bookings/rules.py`` and
``bookings/quotas.py``; the locks' order in ``bookings/services/reservations.py``.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any, Literal

from django.db import connection

from bookings.models import Blackout, QuotaPolicy, Reservation, ReservationItem, Resource
from core import sql
from core.accounts.models import User

ConflictKind = Literal["blackout", "booked"]


def _rows(query: str, params: Sequence[Any]) -> list[tuple[Any, ...]]:
    with connection.cursor() as cursor:
        cursor.execute(query, params)
        return cursor.fetchall()


def conflicts(
    resource_ids: Sequence[int],
    start_at: datetime,
    end_at: datetime,
    *,
    exclude_reservation_id: int | None = None,
    first_only: bool = False,
) -> list[tuple[ConflictKind, int]]:
    """The maintenance windows (``"blackout"``, a ``Blackout`` id) and the active booked
    items (``"booked"``, a ``ReservationItem`` id) on these resources that share an instant
    with ``[start_at, end_at)``: maintenance first, each kind by start; one round trip (a
    UNION). ``first_only``: only the first of them."""
    if not resource_ids:
        return []
    period = [sql.instant_param(end_at), sql.instant_param(start_at)]
    in_ids = sql.placeholders(len(resource_ids))
    excluded = ""
    params: list[Any] = [*period, *resource_ids, *period, *resource_ids]
    if exclude_reservation_id is not None:
        excluded = " AND i.reservation_id <> %s"
        params.append(exclude_reservation_id)
    # "blackout" sorts before "booked": a maintenance window is the better explanation.
    query = (
        f"SELECT 'blackout' AS kind, b.id, b.start_at FROM {sql.table(Blackout)} b "
        f"WHERE {sql.overlap('b')} AND (b.all_resources OR b.id IN "
        f"(SELECT t.blackout_id FROM {sql.table(Blackout.resources.through)} t "
        f"WHERE t.resource_id IN ({in_ids}))) "
        "UNION ALL "
        f"SELECT 'booked' AS kind, i.id, i.start_at FROM {sql.table(ReservationItem)} i "
        f"WHERE {sql.overlap('i')} AND i.active AND i.resource_id IN ({in_ids}){excluded} "
        "ORDER BY 1, 3" + (" LIMIT 1" if first_only else "")
    )
    return [(kind, int(pk)) for kind, pk, _ in _rows(query, params)]


def resources_locked(owner_id: int, resource_ids: Sequence[int]) -> list[Resource]:
    """Lock the owner's row, then these resources in id order, until the transaction ends;
    the resources as locked, in id order.

    PostgreSQL: one round trip, the owner's row first (the CTE yields it before the join can
    give a resource row to lock). SQLite has no row locks: each transaction takes the
    database's write lock as it begins (``transaction_mode`` IMMEDIATE in settings), so
    bookings run one at a time and a plain read is the same answer.
    """
    ids = sorted(set(resource_ids))
    if not sql.is_postgresql():
        return list(Resource.objects.filter(pk__in=ids).order_by("pk"))
    in_ids = sql.placeholders(len(ids))
    query = (
        f"WITH owner AS MATERIALIZED (SELECT id FROM {sql.table(User)} WHERE id = %s "
        f"FOR UPDATE) SELECT r.* FROM {sql.table(Resource)} r, owner WHERE r.id IN ({in_ids}) "
        "ORDER BY r.id FOR UPDATE OF r"
    )
    return list(Resource.objects.raw(query, [owner_id, *ids]))


def _in_scope(policy: QuotaPolicy, user: User, states: Sequence[str]) -> tuple[str, list[Any]]:
    """The user's reservations in ``states`` that ``policy`` counts (those holding a resource
    in its scope): the FROM and WHERE of a query on reservations ``r``, and its parameters.
    The one spelling of a policy's scope."""
    query = (
        f"FROM {sql.table(Reservation)} r "
        f"WHERE r.owner_id = %s AND r.state IN ({sql.placeholders(len(states))})"
    )
    params: list[Any] = [user.pk, *states]
    items = sql.table(ReservationItem)
    if policy.resource_id is not None:
        query += (
            f" AND EXISTS (SELECT 1 FROM {items} i "
            "WHERE i.reservation_id = r.id AND i.resource_id = %s)"
        )
        params.append(policy.resource_id)
    if policy.resource_group_id is not None:
        query += (
            f" AND EXISTS (SELECT 1 FROM {items} i "
            f"JOIN {sql.table(Resource.groups.through)} g ON g.resource_id = i.resource_id "
            "WHERE i.reservation_id = r.id AND g.resourcegroup_id = %s)"
        )
        params.append(policy.resource_group_id)
    return query, params


def quota_periods(
    policy: QuotaPolicy,
    user: User,
    states: Sequence[str],
    period_start: datetime,
    period_end: datetime,
    *,
    exclude_id: int | None = None,
) -> list[tuple[datetime, datetime]]:
    """``(start_at, end_at)`` in UTC of each of the user's reservations in ``states`` that
    ``policy`` counts and that shares an instant with ``[period_start, period_end)``; in no
    particular order. The instants are read as text (``sql.instant``)."""
    scope, params = _in_scope(policy, user, states)
    query = (
        f"SELECT {sql.instant('r.start_at')}, {sql.instant('r.end_at')} {scope} "
        f"AND {sql.overlap('r')}"
    )
    params += [sql.instant_param(period_end), sql.instant_param(period_start)]
    if exclude_id is not None:
        query += " AND r.id <> %s"
        params.append(exclude_id)
    return [(sql.instant_from(start), sql.instant_from(end)) for start, end in _rows(query, params)]


def quota_upcoming(
    policy: QuotaPolicy,
    user: User,
    states: Sequence[str],
    *,
    now: datetime,
    exclude_id: int | None = None,
) -> int:
    """How many of the user's reservations in ``states`` that ``policy`` counts end after
    ``now`` (still to come, or running)."""
    scope, params = _in_scope(policy, user, states)
    query = f"SELECT COUNT(*) {scope} AND r.end_at > %s"
    params.append(sql.instant_param(now))
    if exclude_id is not None:
        query += " AND r.id <> %s"
        params.append(exclude_id)
    return int(_rows(query, params)[0][0])
