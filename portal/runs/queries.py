"""The runs' hand-written SQL: a run's samples in and out in bulk.

A run holds tens of thousands of samples; passing them one ORM object at a time costs more
than everything else a collection round or a page does. On PostgreSQL the database takes a
page in by binary ``COPY``, writes the downloads itself (``COPY … TO STDOUT``) and packs the
run page's columns into arrays. Those queries are PostgreSQL's alone
(``sql.postgresql_only``): their callers (``services/collection.py``, ``selectors.py``) hold
the path for SQLite, and ``tests/test_queries_sqlite.py`` holds the two paths to the same
answer. Built from ``core.sql``'s helpers, the contract's column names and bound parameters
only (``tests/test_architecture.py``).
"""

from __future__ import annotations

import functools
from collections.abc import Iterator, Sequence
from typing import Any, Final

import numpy as np
from django.db import connection
from django.db.models import FloatField, Func, Max

from basestation.contract import SAMPLE_COLUMNS, SAMPLE_FIELDS
from core import sql
from portal.runs.analysis import SampleColumns, SampleRow
from portal.runs.models import MeasurementPoint, Run, Sample

# The samples' columns after run_id, in the contract's order (by name, never position).
_COLUMNS: Final = ", ".join(SAMPLE_FIELDS)

# --- In: a page of samples by COPY ------------------------------------------------------------


@functools.cache
def _copy_types(with_run: bool) -> tuple[str, ...]:
    """The column types of a binary ``COPY`` of a page (the run id first when ``with_run``),
    the model's own (the contract test keeps model and contract in step)."""
    names = ["run", *SAMPLE_FIELDS] if with_run else SAMPLE_FIELDS
    # varchar(n) travels as text: the same bytes, and the column still checks n.
    return tuple(sql.column_type(Sample, name).partition("(")[0] for name in names)


def _copy_rows(
    cursor: Any, statement: str, rows: Sequence[tuple[Any, ...]], run_id: int | None
) -> None:
    """``rows`` by the binary ``COPY … FROM STDIN`` ``statement``, each after ``run_id``
    unless None: the database reads the values as they are, instead of parsing the text of
    each number and time; a page goes in faster than by a plain text ``COPY``."""
    head = () if run_id is None else (run_id,)
    with cursor.copy(statement) as copy:
        copy.set_types(_copy_types(run_id is not None))
        for row in rows:
            copy.write_row((*head, *row))


@sql.postgresql_only
def samples_copy(run_id: int, rows: Sequence[tuple[Any, ...]]) -> None:
    """Store ``rows`` (the contract's columns in order, ``t`` an aware datetime) as samples of
    the run, straight into the table. A row stored already fails the whole statement: psycopg
    raises ``UniqueViolation`` itself (``COPY`` goes to it directly, unwrapped by Django)."""
    statement = f"COPY {sql.table(Sample)} (run_id, {_COLUMNS}) FROM STDIN WITH (FORMAT BINARY)"
    with connection.cursor() as cursor:
        _copy_rows(cursor, statement, rows, run_id)


@sql.postgresql_only
def samples_merge(run_id: int, rows: Sequence[tuple[Any, ...]]) -> list[int]:
    """Store those of ``rows`` (as :func:`samples_copy` takes them) not stored yet, through a
    temporary table; the sequence numbers that were new."""
    # The contract's columns with the model's types (the contract test keeps them in step).
    definitions = ", ".join(f"{name} {sql.column_type(Sample, name)}" for name in SAMPLE_FIELDS)
    with connection.cursor() as cursor:
        # One per connection serves every page.
        cursor.execute(
            f"CREATE TEMPORARY TABLE IF NOT EXISTS sample_page ({definitions}) "
            "ON COMMIT DELETE ROWS"
        )
        _copy_rows(
            cursor, f"COPY sample_page ({_COLUMNS}) FROM STDIN WITH (FORMAT BINARY)", rows, None
        )
        cursor.execute(
            f"INSERT INTO {sql.table(Sample)} (run_id, {_COLUMNS}) SELECT %s, {_COLUMNS} "
            "FROM sample_page ON CONFLICT (run_id, seq) DO NOTHING RETURNING seq",
            [run_id],
        )
        stored = [int(row[0]) for row in cursor.fetchall()]
        # Emptied now too: a caller's transaction holding several pages (one commit for
        # all) must not merge a page's rows again with the next one.
        cursor.execute("DELETE FROM sample_page")
        return stored


# --- Out: the downloads, written by the database ----------------------------------------------

# What a download hands the web server at a time: enough that the per-chunk costs (a write,
# a gzip call, a thread hop under ASGI) vanish, little enough to stream.
CHUNK_BYTES = 256 * 1024


def _utc_text(column: str) -> str:
    """The instant ``column`` as the downloads write it (``selectors.CSV_TIME_FORMAT``): UTC,
    always six digits of microseconds, then Z. The timestamp's own text (ISO, which the
    driver requires anyway) drops trailing zeros and a zero fraction; padding them back costs
    a third of what ``to_char`` does (with which the CSV took 30 % longer than a plain COPY)."""
    name = sql.identifier(column)
    return (
        f"rpad(replace(({name} AT TIME ZONE 'UTC')::text, ' ', 'T') "
        f"|| CASE WHEN {name} = date_trunc('second', {name}) THEN '.' ELSE '' END, 26, '0') "
        "|| 'Z'"
    )


def _csv_text(column: str) -> str:
    """The text ``column`` as the CSV writes it, escaped as ``basestation.contract.csv_cell``
    does (an apostrophe before a formula's first character): the agent's values are checked
    at ingest, but a spreadsheet must not run one that got through."""
    name = sql.identifier(column)
    return (
        f"CASE WHEN left({name}, 1) IN ('=', '+', '-', '@', chr(9), chr(13)) "
        f"THEN '''' || {name} ELSE {name} END"
    )


_CSV_SELECT: Final = ", ".join(
    _utc_text(column.name)
    if column.name == "t"
    else _csv_text(column.name)
    if column.kind == "text"
    else column.name
    for column in SAMPLE_COLUMNS
)


def _json_values() -> tuple[str, tuple[bytes, ...]]:
    """The select list of ``COPY`` (text format, NULL written as ``null``) whose fields are
    each sample's JSON values, and the literal pieces that go before each field (the last
    one closes the object): joined alternately, a chunk of rows is a run of JSON objects
    (see ``selectors.run_samples_json``).

    The database does no more per row than for the CSV: each value is a column as it is
    (numbers as the text that reads back exactly, NULL as ``null``), the time as in the CSV.
    Quotes around a value that is never NULL are in the pieces; the contract's words need
    no escaping (ingest lets no other in); free text goes through ``to_json``.
    """
    values, pieces, before = [], [], '},{"'
    for column in SAMPLE_COLUMNS:
        name = column.name
        quoted = column.kind == "epoch" or (
            column.kind == "text"
            and not column.nullable
            and column.choices is not None
            and all(c.isalnum() for c in column.choices)
        )
        opening = '"' if quoted else ""
        pieces.append(f'{before}{name}":{opening}'.encode())
        before = '","' if quoted else ',"'
        if column.kind == "epoch":
            values.append(_utc_text(name))
        elif column.kind == "text" and not quoted:
            values.append(f"to_json({name})")
        else:
            values.append(name)
    pieces.append(b'"}' if before == '","' else b"}")
    return ", ".join(values), tuple(pieces)


_JSON_SELECT, SAMPLE_JSON_PIECES = _json_values()


def _copy_out(statement: str) -> Iterator[bytes]:
    """The rows of ``COPY (…) TO STDOUT``, gathered into chunks of whole rows.

    libpq hands over one row per call; passing each on alone would cost more than the
    database's work of producing it. Each row is copied into the chunk at once, so libpq's
    buffer is freed while still warm (holding on to them costs a tenth of the download).
    """
    with connection.cursor() as cursor, cursor.copy(statement) as copy:
        chunk = bytearray()
        for row in copy:
            chunk += row
            if len(chunk) >= CHUNK_BYTES:
                yield bytes(chunk)
                chunk.clear()
        if chunk:
            yield bytes(chunk)


# COPY takes no bound parameters through Django's debug cursor: the run id goes in as an
# integer, everything else is the contract's and the model's.


@sql.postgresql_only
def samples_csv_copy(run_id: int) -> Iterator[bytes]:
    """The run's samples by ``seq`` as CSV rows written by the database (no header), in
    chunks of whole rows: the contract's columns in order, times as ``_utc_text``."""
    return _copy_out(
        f"COPY (SELECT {_CSV_SELECT} FROM {sql.table(Sample)} "
        f"WHERE run_id = {int(run_id)} ORDER BY seq) TO STDOUT WITH (FORMAT csv)"
    )


@sql.postgresql_only
def samples_json_copy(run_id: int) -> Iterator[bytes]:
    """The run's samples by ``seq`` as rows of JSON values in ``COPY``'s text format (a tab
    between fields, a newline after each row, backslashes doubled, NULL as ``null``), in
    chunks of whole rows; put after :data:`SAMPLE_JSON_PIECES` in turn, they are the
    samples' JSON objects."""
    return _copy_out(
        f"COPY (SELECT {_JSON_SELECT} FROM {sql.table(Sample)} "
        f"WHERE run_id = {int(run_id)} ORDER BY seq) TO STDOUT WITH (NULL 'null')"
    )


# --- The run page's columns -------------------------------------------------------------------


class EpochSeconds(Func):
    """A timestamp as float seconds since 1970, computed by the database.

    Reading 72 000 timestamps as datetimes costs more than the whole analysis (the driver
    parses each one in Python); a float costs nothing.
    """

    output_field = FloatField()
    template = "CAST(EXTRACT(EPOCH FROM %(expressions)s) AS double precision)"

    def as_sqlite(self, compiler: Any, connection: Any, **extra: Any) -> Any:
        # SQLite keeps "YYYY-MM-DD HH:MM:SS.ffffff" in UTC; 2440587.5 is 1970-01-01 in Julian days.
        return self.as_sql(
            compiler, connection, template="((julianday(%(expressions)s) - 2440587.5) * 86400.0)"
        )


# The columns the run page reads, each as a float8 (NULL as NaN, the direction as 1.0 for
# ccw), packed by the database into bytes that numpy reads as they are: no number is
# formatted as text and parsed back, and no row passes through Python on its own.
_REPORT_COLUMNS: Final = (
    "seq::float8",
    "EXTRACT(EPOCH FROM t)::float8",
    "coalesce(segment::float8, 'NaN')",
    "commanded_velocity_mps",
    "velocity_mps",
    "(direction = 'ccw')::int::float8",
    "battery_v",
    "track_m",
    "coalesce(fix_quality::float8, 'NaN')",
)
_REPORT_ARRAYS: Final = ", ".join(f"array_send(array_agg({column}))" for column in _REPORT_COLUMNS)
# Samples per aggregated value: a day-long run comes as ~30 values a column, never one huge.
_PACK_SEQS = 65536
# ``array_send`` of a one-dimensional float8 array: a 20-byte header, then each element as
# its length (8) and its value, big-endian.
_ARRAY_HEADER_BYTES = 20
_ARRAY_ELEMENT = np.dtype([("length", ">i4"), ("value", ">f8")])


def _array(data: bytes) -> np.ndarray:
    elements = np.frombuffer(data, dtype=_ARRAY_ELEMENT, offset=_ARRAY_HEADER_BYTES)
    if int.from_bytes(data[:4], "big") != 1 or not (elements["length"] == 8).all():
        raise RuntimeError("array_send gave something other than a float8 vector")
    return elements["value"].astype(np.float64)


def _sample_arrays(run: Run) -> list[np.ndarray]:
    """The columns in binary, one array per column: the database sends each as one value
    (``array_send``), numpy reads it as it is, and no sample passes through Python alone.
    Aggregated in any order, they are put in ``seq`` order here."""
    query = (
        f"SELECT {_REPORT_ARRAYS} FROM {sql.table(Sample)} "
        "WHERE run_id = %s AND seq >= %s AND seq < %s"
    )
    last_seq = Sample.objects.filter(run=run).aggregate(last=Max("seq"))["last"] or 0
    parts = []
    with connection.cursor() as cursor:
        # A range of seq at a time, read along the (run, seq) index: no sort, no hash.
        for first in range(0, last_seq + 1, _PACK_SEQS):
            cursor.execute(query, [run.pk, first, first + _PACK_SEQS])
            part = cursor.fetchone()
            if part is not None and part[0] is not None:
                parts.append(part)
    if not parts:
        return [np.zeros(0) for _ in _REPORT_COLUMNS]
    columns = [
        np.concatenate([_array(bytes(part[i])) for part in parts])
        for i in range(len(_REPORT_COLUMNS))
    ]
    seq = columns[0]
    if len(seq) > 1 and not (seq[1:] > seq[:-1]).all():
        order = np.argsort(seq, kind="stable")
        columns = [column[order] for column in columns]
    return columns


def _sample_columns_read(run: Run) -> SampleColumns:
    """The same through the ORM's SQL and a chunked cursor (SQLite has no arrays to send)."""
    rows = (
        Sample.objects.filter(run=run)
        .order_by("seq")
        .annotate(t_epoch_s=EpochSeconds("t"))
        .values_list(*(("t_epoch_s" if f == "t_s" else f) for f in SampleRow._fields))
    )
    # Every column is a plain number or string already: Django's per-row converters would
    # cost more than the whole analysis. Each batch is turned into columns in C (``zip``).
    query, params = rows.query.sql_with_params()
    lists: list[list[Any]] = [[] for _ in SampleRow._fields]
    with connection.chunked_cursor() as cursor:
        cursor.execute(query, params)
        while batch := cursor.fetchmany(5000):
            for column, values in zip(lists, zip(*batch, strict=True), strict=True):
                column.extend(values)
    return SampleColumns.from_lists(*lists)


def sample_columns(run: Run) -> SampleColumns:
    """The run's samples a column at a time in ``seq`` order, ``t_s`` in seconds since 1970.

    PostgreSQL packs each column into arrays (``_sample_arrays``); SQLite's rows are read
    through a chunked cursor. Both are read as numbers, never as Python objects per value."""
    if not sql.is_postgresql():
        return _sample_columns_read(run)
    seq, t, segment, commanded, measured, ccw, battery, track, fix = _sample_arrays(run)
    return SampleColumns(
        seq.astype(np.int64), t, segment, commanded, measured, ccw == 1.0, battery, track, fix
    )


# --- A researcher's measurement points, in and out by binary COPY ----------------------------

# PostgreSQL's binary COPY: its signature, no flags, no header extension; the end mark.
_PGCOPY_HEAD: Final = b"PGCOPY\n\xff\r\n\x00" + b"\x00" * 8
_PGCOPY_END: Final = b"\xff\xff"
# Its times count microseconds from 2000-01-01 UTC.
_PG_EPOCH_US: Final = 946_684_800 * 1_000_000
# A point's row as binary COPY writes it: the field count, then each field's length and
# value (series id, column, time, value; none is ever NULL), big-endian.
_POINT_ROW: Final = np.dtype(
    [
        ("fields", ">i2"),
        ("series_len", ">i4"),
        ("series", ">i8"),
        ("column_len", ">i4"),
        ("column_index", ">i2"),
        ("t_len", ">i4"),
        ("t", ">i8"),
        ("value_len", ">i4"),
        ("value", ">f8"),
    ]
)
# What is read back: column, time, value.
_POINT_OUT: Final = np.dtype(
    [
        ("fields", ">i2"),
        ("column_len", ">i4"),
        ("column_index", ">i2"),
        ("t_len", ">i4"),
        ("t", ">i8"),
        ("value_len", ">i4"),
        ("value", ">f8"),
    ]
)
_POINT_FIELDS: Final = "series_id, column_index, t, value"


def _points_binary(series_id: int, column: int, times_us: np.ndarray, values: np.ndarray) -> bytes:
    """The points as one binary COPY stream, built by numpy in one pass: no Python object
    per point (a million points are a few tens of megabytes, written in a few milliseconds)."""
    rows = np.empty(len(times_us), dtype=_POINT_ROW)
    rows["fields"] = 4
    rows["series_len"], rows["series"] = 8, series_id
    rows["column_len"], rows["column_index"] = 2, column
    rows["t_len"], rows["t"] = 8, times_us - _PG_EPOCH_US
    rows["value_len"], rows["value"] = 8, values
    return _PGCOPY_HEAD + rows.tobytes() + _PGCOPY_END


@sql.postgresql_only
def measurement_points_copy(
    series_id: int, column: int, times_us: np.ndarray, values: np.ndarray
) -> None:
    """Store the points straight into the table by binary ``COPY``. A point stored already
    fails the whole statement (psycopg's ``UniqueViolation``): the caller merges then."""
    statement = (
        f"COPY {sql.table(MeasurementPoint)} ({_POINT_FIELDS}) FROM STDIN WITH (FORMAT BINARY)"
    )
    with connection.cursor() as cursor, cursor.copy(statement) as copy:
        copy.write(_points_binary(series_id, column, times_us, values))


@sql.postgresql_only
def measurement_points_merge(
    series_id: int, column: int, times_us: np.ndarray, values: np.ndarray
) -> int:
    """Store those of the points not stored yet, through a temporary table; how many were
    new. (A point at a time stored already keeps its stored value.)"""
    table = sql.table(MeasurementPoint)
    with connection.cursor() as cursor:
        cursor.execute(
            "CREATE TEMPORARY TABLE IF NOT EXISTS measurement_page (series_id bigint, "
            "column_index smallint, t timestamptz, value double precision) ON COMMIT DELETE ROWS"
        )
        with cursor.copy(
            f"COPY measurement_page ({_POINT_FIELDS}) FROM STDIN WITH (FORMAT BINARY)"
        ) as copy:
            copy.write(_points_binary(series_id, column, times_us, values))
        cursor.execute(
            f"INSERT INTO {table} ({_POINT_FIELDS}) SELECT {_POINT_FIELDS} FROM measurement_page "
            "ON CONFLICT DO NOTHING"
        )
        stored = int(cursor.rowcount)
        cursor.execute("DELETE FROM measurement_page")
        return stored


@sql.postgresql_only
def measurement_points_read(series_id: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every point of the series by (column, time): the columns, the times in microseconds
    since 1970 and the values, read by binary ``COPY`` straight into numpy."""
    table = sql.table(MeasurementPoint)
    data = b"".join(
        _copy_out(
            f"COPY (SELECT column_index, t, value FROM {table} WHERE series_id = {int(series_id)} "
            "ORDER BY column_index, t) TO STDOUT WITH (FORMAT BINARY)"
        )
    )
    # The head: the signature and flags, then the header extension's length and bytes.
    extension = int.from_bytes(data[15:19], "big")
    body = data[19 + extension : len(data) - len(_PGCOPY_END)]
    rows = np.frombuffer(body, dtype=_POINT_OUT)
    return (
        rows["column_index"].astype(np.int64),
        rows["t"].astype(np.int64) + _PG_EPOCH_US,
        rows["value"].astype(np.float64),
    )
