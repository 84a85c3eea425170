"""Hand-written SQL: the helpers every query is built from, the database switch, and core's
own two statements (the health probe and the advisory locks).

The portal asks the database through the ORM. Where a query is written by hand (a read under
the booking lock on every booking, a ``COPY``, a lock the ORM has no word for) it lives in
its app's ``queries.py`` (``bookings/queries.py``, ``portal/runs/queries.py``) and is built
only from what is here: a table's quoted name, parameter marks, an instant as text, the
overlap condition, a checked identifier. Every value is a bound parameter.
``tests/test_architecture.py`` holds the code to that: SQL text only in those homes, and
nothing formatted into it but these helpers, ``int(...)``, module constants and locals made
of them. Which database answers is asked here and nowhere else (:func:`is_postgresql`);
``tests/test_queries_sqlite.py`` runs every query on SQLite too, the embedded default.
"""

from __future__ import annotations

import contextlib
import functools
import re
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from typing import ParamSpec, TypeVar

from django.db import NotSupportedError, connection, models

_P = ParamSpec("_P")
_R = TypeVar("_R")

# A column, or ``alias.column``, as the query modules write them: lower case, no quoting.
_IDENTIFIER = re.compile(r"[a-z_][a-z0-9_]*(?:\.[a-z_][a-z0-9_]*)?")


# --- Which database ---------------------------------------------------------------------------


def is_postgresql() -> bool:
    """Whether the default database is PostgreSQL (production); otherwise it is SQLite."""
    return connection.vendor == "postgresql"


def is_sqlite() -> bool:
    return connection.vendor == "sqlite"


def database_kind() -> str:
    """The default database's kind as one word (``postgresql``, ``sqlite``), for keys."""
    return connection.vendor


def postgresql_only(query: Callable[_P, _R]) -> Callable[_P, _R]:
    """Mark a query as PostgreSQL's alone (``COPY``, arrays): on another database it raises
    ``NotSupportedError`` before any SQL is sent. Its caller holds the other path, and the
    SQLite test compares what that path answers with what this one does."""

    @functools.wraps(query)
    def checked(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        if not is_postgresql():
            raise NotSupportedError(f"{query.__name__} runs on PostgreSQL only")
        return query(*args, **kwargs)

    checked.postgresql_only = True  # type: ignore[attr-defined]
    return checked


# --- Building a query -------------------------------------------------------------------------


def identifier(name: str) -> str:
    """``name``, a lower-case column or ``alias.column``; ``ValueError`` for anything else.

    The helpers that put a name into SQL take names their callers write, never input; this
    keeps it so should that ever change."""
    if not _IDENTIFIER.fullmatch(name):
        raise ValueError(f"not a plain SQL name: {name!r}")
    return name


def table(model: type[models.Model]) -> str:
    """``model``'s table, quoted."""
    return connection.ops.quote_name(model._meta.db_table)


def column_type(model: type[models.Model], field_name: str) -> str:
    """The database type of ``model``'s field ``field_name`` (as its migration made it)."""
    field = model._meta.get_field(field_name)
    db_type = field.db_type(connection) if isinstance(field, models.Field) else None
    if db_type is None:
        raise ValueError(f"{model.__name__}.{field_name} has no column")
    return str(db_type)


def placeholders(count: int) -> str:
    """``count`` parameter marks, as in ``IN (%s, %s)``; at least one (``IN ()`` is no SQL)."""
    if count < 1:
        raise ValueError(f"{count} parameter marks")
    return ", ".join(["%s"] * count)


def instant_param(value: datetime) -> object:
    """An instant as a query takes it as a parameter (as the ORM would pass it)."""
    return connection.ops.adapt_datetimefield_value(value)


def instant(column: str) -> str:
    """A ``DateTimeField`` column read as ISO 8601 text in UTC (:func:`instant_from` turns it
    back), for queries that read many rows: Django reads a timestamptz through a Python call
    per value, five times slower than ``datetime.fromisoformat`` on this text."""
    name = identifier(column)
    if is_postgresql():
        return f"to_char({name} AT TIME ZONE 'UTC', 'YYYY-MM-DD\"T\"HH24:MI:SS.US')"
    return name  # SQLite keeps a UTC instant as such text already


def instant_from(value: str | datetime) -> datetime:
    """What :func:`instant` read, as an aware UTC datetime."""
    read = value if isinstance(value, datetime) else datetime.fromisoformat(value)
    return read.replace(tzinfo=UTC)


def overlap(alias: str) -> str:
    """``PeriodQuerySet.overlapping`` for hand-written SQL: the row ``alias`` shares an
    instant with ``[%s, %s)``, the parameters given as (end, start). Back to back is no
    overlap, as everywhere (``bookings/periods.py``)."""
    row = identifier(alias)
    return f"{row}.start_at < %s AND {row}.end_at > %s"


# --- Core's own statements --------------------------------------------------------------------


def ping() -> None:
    """Ask the database the smallest question; raises whatever reaching it raises."""
    with connection.cursor() as cursor:
        cursor.execute("SELECT 1")
        cursor.fetchone()


# How often a bounded wait for an advisory lock tries again.
ADVISORY_RETRY_S = 0.02


def advisory_key(data: bytes) -> int:
    """An advisory lock's key: the first eight bytes of ``data`` as a signed 64-bit number."""
    return int.from_bytes(data[:8], "big", signed=True)


def advisory_xact_lock(key: int) -> None:
    """Hold the lock ``key`` until the current transaction ends, waiting while another
    transaction holds it (PostgreSQL). Nothing to take on SQLite: its transactions begin
    ``IMMEDIATE`` (settings), so a transaction that writes holds the whole database already."""
    if is_postgresql():
        with connection.cursor() as cursor:
            cursor.execute("SELECT pg_advisory_xact_lock(%s)", [key])


@contextlib.contextmanager
def advisory_session_lock(key: int) -> Iterator[None]:
    """Hold the lock ``key`` for the block, across the transactions in it, waiting while
    another session holds it (PostgreSQL); a session that dies lets it go with its
    connection. Nothing to take on SQLite, as :func:`advisory_xact_lock` says why."""
    if not is_postgresql():
        yield
        return
    with connection.cursor() as cursor:
        cursor.execute("SELECT pg_advisory_lock(%s)", [key])
    try:
        yield
    finally:
        with connection.cursor() as cursor:
            cursor.execute("SELECT pg_advisory_unlock(%s)", [key])


def advisory_xact_lock_within(key: int, wait_s: float) -> bool:
    """:func:`advisory_xact_lock`, waiting at most ``wait_s``: False when another transaction
    held it all that time (a process frozen inside it holds it until its connection dies).
    True on SQLite, as :func:`advisory_xact_lock` says why."""
    deadline = time.monotonic() + wait_s
    while not try_advisory_xact_lock(key):
        if time.monotonic() >= deadline:
            return False
        time.sleep(ADVISORY_RETRY_S)
    return True


def try_advisory_xact_lock(key: int) -> bool:
    """Take the lock ``key`` until the current transaction ends, without waiting: False when
    another transaction holds it. True on SQLite, as :func:`advisory_xact_lock` says why."""
    if not is_postgresql():
        return True
    with connection.cursor() as cursor:
        cursor.execute("SELECT pg_try_advisory_xact_lock(%s)", [key])
        row = cursor.fetchone()
    return bool(row and row[0])
