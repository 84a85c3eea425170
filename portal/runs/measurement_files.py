"""A researcher's measurement file read into points: CSV, JSON or Parquet, with pyarrow.

One time column and one or more value columns. Times are RFC 3339 with a UTC offset (``Z``
or ``±hh:mm``) or Unix seconds; a time without an offset is refused, never guessed (the
researcher's laptop and the base station may not share a time zone). Values are numbers; an
empty cell is a missing value. Whatever is wrong is said with the column and the row, and
nothing is read half: :class:`MeasurementFileError` or every point.

Plain pyarrow and numpy, no Django: the upload service (``portal/runs/measurements.py``)
checks the points against the run and stores them.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from typing import Final

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from basestation.contract import CSV_FORMULA_PREFIXES

FORMATS: Final = ("csv", "json", "parquet")
# The time column's name when none is given: the first of these the file has.
TIME_COLUMNS: Final = ("t", "time", "timestamp", "time_s", "unix_s", "datetime")
MAX_COLUMNS: Final = 16
# A series's table (``measurement_tables.py``) has these columns of its own beside the values.
RESERVED_NAMES: Final = frozenset({"t", "t_base"})
RESERVED_PREFIX: Final = "robot_"


class MeasurementFileError(ValueError):
    """The file cannot be read as points; the message says where and why."""


@dataclass(frozen=True)
class Points:
    """Points read from a file: ``times_s`` (Unix seconds, UTC, float64) and one value
    array per column (float64, ``NaN`` where the file had no value), in the file's order."""

    times_s: np.ndarray
    columns: list[str]
    values: list[np.ndarray]

    def __len__(self) -> int:
        return len(self.times_s)


def format_of(filename: str, declared: str = "") -> str:
    """The file's format: ``declared`` if given, else its name's extension."""
    extension = filename.rsplit(".", 1)[-1] if "." in filename else ""
    fmt = (declared or extension).lower()
    if fmt in ("pq", "parq"):
        fmt = "parquet"
    if fmt not in FORMATS:
        raise MeasurementFileError(
            f"cannot tell the file's format from {filename!r}: name it .csv, .json or "
            ".parquet, or give the format"
        )
    return fmt


def _table(data: bytes, fmt: str) -> pa.Table:
    try:
        if fmt == "csv":
            table = pa_csv.read_csv(io.BytesIO(data))
        elif fmt == "parquet":
            table = pq.read_table(io.BytesIO(data))
        else:
            return _json_table(data)
        # Its names decoded here: pyarrow takes a header's bytes as they come.
        table.column_names  # noqa: B018
        return table
    except (pa.ArrowException, OSError, UnicodeDecodeError) as exc:
        # A picture sent as CSV fails in its header's decoding, not in Arrow.
        raise MeasurementFileError(f"not a readable {fmt.upper()} file: {exc}") from None


def _json_table(data: bytes) -> pa.Table:
    """``[{"t": …, "rssi": …}, …]`` or ``{"points": [ … ]}``."""
    try:
        document = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MeasurementFileError(f"not a readable JSON file: {exc}") from None
    return rows_table(document.get("points") if isinstance(document, dict) else document)


def rows_table(rows: object) -> pa.Table:
    """Points given as objects (a JSON file's, an API batch's) as a table of columns."""
    if not isinstance(rows, list) or not all(isinstance(row, dict) for row in rows):
        raise MeasurementFileError(
            'points are a list of objects ({"t": …, "rssi": …}), or {"points": [ … ]}'
        )
    names: dict[str, None] = {}
    for row in rows:
        names.update(dict.fromkeys(row))
    # Each column as Python gives it; the checks below say what is wrong with a value.
    return pa.table({name: pa.array([_json_cell(row.get(name)) for row in rows]) for name in names})


def _json_cell(cell: object) -> object:
    # Numbers and text as they are; anything else (a list, an object, true) made text, so
    # that the column check refuses it by its row instead of pyarrow failing on a mixed type.
    if cell is None or (isinstance(cell, (int, float, str)) and not isinstance(cell, bool)):
        return str(cell) if isinstance(cell, int) and abs(cell) > 2**53 else cell
    return json.dumps(cell)


def _first_bad_row(column: pa.ChunkedArray, ok: np.ndarray) -> str:
    row = int(np.flatnonzero(~ok)[0])
    return f"row {row + 1} ({column[row].as_py()!r})"


def _times_s(name: str, column: pa.ChunkedArray) -> np.ndarray:
    kind = column.type
    if pa.types.is_timestamp(kind):
        if kind.tz is None:
            raise MeasurementFileError(
                f"column {name!r}: times need a UTC offset (Z or ±hh:mm), or give Unix seconds"
            )
        micros = pc.cast(column, pa.timestamp("us", tz="UTC")).cast(pa.int64())
        times = micros.to_numpy(zero_copy_only=False).astype(np.float64) / 1e6
    elif pa.types.is_integer(kind) or pa.types.is_floating(kind):
        times = column.to_numpy(zero_copy_only=False).astype(np.float64)
    elif pa.types.is_string(kind) or pa.types.is_large_string(kind):
        return _times_from_text(name, column)
    else:
        raise MeasurementFileError(f"column {name!r}: {kind} is not a time")
    if column.null_count:
        ok = ~np.asarray(column.is_null().to_numpy(zero_copy_only=False))
        raise MeasurementFileError(f"column {name!r}: no time at {_first_bad_row(column, ok)}")
    return times


def _times_from_text(name: str, column: pa.ChunkedArray) -> np.ndarray:
    """RFC 3339 text, or numbers written as text (a JSON file's mixed column)."""
    try:
        return pc.cast(column, pa.float64()).to_numpy(zero_copy_only=False)
    except pa.ArrowInvalid:
        pass
    try:
        stamps = pc.cast(column, pa.timestamp("us", tz="UTC"))
    except pa.ArrowInvalid as exc:
        text = str(exc)
        why = (
            "times need a UTC offset (Z or ±hh:mm), or give Unix seconds"
            if "zone offset" in text
            else "not an RFC 3339 time or Unix seconds"
        )
        ok = np.array([_parses(cell) for cell in column.to_pylist()])
        where = _first_bad_row(column, ok) if not ok.all() else "a row"
        raise MeasurementFileError(f"column {name!r}, {where}: {why}") from None
    if stamps.null_count:
        ok = ~np.asarray(stamps.is_null().to_numpy(zero_copy_only=False))
        raise MeasurementFileError(f"column {name!r}: no time at {_first_bad_row(column, ok)}")
    return stamps.cast(pa.int64()).to_numpy(zero_copy_only=False).astype(np.float64) / 1e6


def _parses(cell: object) -> bool:
    try:
        pc.cast(pa.array([cell]), pa.timestamp("us", tz="UTC"))
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError):
        return False
    return True


def _values(name: str, column: pa.ChunkedArray) -> np.ndarray:
    kind = column.type
    if pa.types.is_null(kind):
        return np.full(len(column), np.nan)
    if pa.types.is_integer(kind) or pa.types.is_floating(kind):
        return column.cast(pa.float64()).to_numpy(zero_copy_only=False)
    if pa.types.is_string(kind) or pa.types.is_large_string(kind):
        try:
            return pc.cast(column, pa.float64()).to_numpy(zero_copy_only=False)
        except pa.ArrowInvalid:
            texts = column.to_pylist()
            ok = np.array([text is None or _is_number(text) for text in texts])
            raise MeasurementFileError(
                f"column {name!r}: not a number at {_first_bad_row(column, ok)}"
            ) from None
    raise MeasurementFileError(f"column {name!r}: {kind} values are not numbers")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _check_column_name(name: str) -> None:
    if not name.strip() or len(name) > 64:
        raise MeasurementFileError(f"a value column's name is 1 to 64 characters: {name!r}")
    if name.startswith(CSV_FORMULA_PREFIXES):
        raise MeasurementFileError(
            f"a value column's name may not begin with = + - @ (a spreadsheet's formula): {name!r}"
        )
    if name in RESERVED_NAMES or name.startswith(RESERVED_PREFIX):
        raise MeasurementFileError(
            f"the value column {name!r} would clash with the series's own columns "
            f"(t, t_base, {RESERVED_PREFIX}…): rename it"
        )


def read_points(
    data: bytes, fmt: str, *, time_column: str = "", columns: list[str] | None = None
) -> Points:
    """The points of a file of format ``fmt``: its ``time_column`` (or the first of
    ``TIME_COLUMNS`` it has) and its value ``columns`` (or every other column)."""
    return table_points(_table(data, fmt), time_column=time_column, columns=columns)


def table_points(
    table: pa.Table, *, time_column: str = "", columns: list[str] | None = None
) -> Points:
    """A table's points, as :func:`read_points` says."""
    names = list(table.column_names)
    if len(set(names)) != len(names):
        raise MeasurementFileError("two columns have the same name")
    if time_column:
        if time_column not in names:
            raise MeasurementFileError(
                f"no column {time_column!r}; the file has {', '.join(names) or 'none'}"
            )
    else:
        found = [name for name in TIME_COLUMNS if name in names]
        if not found:
            raise MeasurementFileError(
                f"no time column: name one ({', '.join(names) or 'the file has no columns'}), "
                f"or call it {' or '.join(TIME_COLUMNS[:3])}"
            )
        time_column = found[0]
    wanted = columns if columns else [name for name in names if name != time_column]
    unknown = [name for name in wanted if name not in names or name == time_column]
    if unknown:
        raise MeasurementFileError(
            f"unknown value column {unknown[0]!r}; the file has {', '.join(names)}"
        )
    if not wanted:
        raise MeasurementFileError("no value column: the file has only its times")
    for name in wanted:
        _check_column_name(name)
    if len(wanted) > MAX_COLUMNS:
        raise MeasurementFileError(
            f"at most {MAX_COLUMNS} value columns, the file has {len(wanted)}"
        )
    if table.num_rows == 0:
        raise MeasurementFileError("the file has no points")
    times = _times_s(time_column, table.column(time_column))
    if not np.all(np.isfinite(times)):
        ok = np.isfinite(times)
        raise MeasurementFileError(
            f"column {time_column!r}: not a time at {_first_bad_row(table.column(time_column), ok)}"
        )
    values = [_values(name, table.column(name)) for name in wanted]
    for name, column in zip(wanted, values, strict=True):
        if np.any(np.isinf(column)):
            row = int(np.flatnonzero(np.isinf(column))[0]) + 1
            raise MeasurementFileError(f"column {name!r}: an infinite value at row {row}")
    return Points(times_s=times, columns=list(wanted), values=values)
