"""A run's data as typed tables: each measurement series placed on the path, and the samples.

One table a series, one row a time of it (the union of its columns' times): the time on the
researcher's clock and on the base station's (the offset added), the value columns, then
where the robot was (``robot_*``: the placement's columns, and the nearer sample's ``seq``, a
foreign key to the samples). The same table goes into the run package as CSV with its Table
Schema (``docs/run-package.md``) and is downloaded as Parquet, as are the samples.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from typing import Any, Final

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from basestation.contract import SAMPLE_COLUMNS, CsvWriter, csv_cell
from portal.runs.measurements import run_track, series_points
from portal.runs.models import MeasurementSeries, Run, Sample
from portal.runs.placement import WHERE_NAMES, Track, place

# Times in the CSV as in the samples' CSV: UTC, ISO 8601 with microseconds and Z.
CSV_TIME_FORMAT: Final = "%Y-%m-%dT%H:%M:%S.%fZ"
UTC_MICROS: Final = pa.timestamp("us", tz="UTC")

# The placement's columns: name, Arrow type, Table Schema type, unit, description.
ROBOT_COLUMNS: Final[tuple[tuple[str, pa.DataType, str, str, str], ...]] = (
    ("robot_where", pa.string(), "string", "",
     "placed (between two samples that follow each other), before (the run's first sample), "
     "after (its last), gap (between samples that do not follow: position unknown)"),
    ("robot_track_m", pa.float64(), "number", "m", "the robot's position along the rail"),
    ("robot_unwrapped_m", pa.float64(), "number", "m",
     "the same, continuous across laps, from the run's first sample"),
    ("robot_lap", pa.int64(), "integer", "", "the lap the robot was on"),
    ("robot_segment", pa.int64(), "integer", "", "the program's segment then"),
    ("robot_commanded_velocity_mps", pa.float64(), "number", "m/s", "the velocity commanded"),
    ("robot_velocity_mps", pa.float64(), "number", "m/s", "the velocity measured, interpolated"),
    ("robot_lat_deg", pa.float64(), "number", "°", "latitude, when both samples had a fix"),
    ("robot_lon_deg", pa.float64(), "number", "°", "longitude, likewise"),
    ("robot_grid_id", pa.string(), "string", "", "the nearer sample's grid cell"),
    ("robot_sample_seq", pa.int64(), "integer", "", "the nearer sample's seq (samples.csv)"),
)  # fmt: skip
_TABLE_TYPES: Final = {"int": pa.int64(), "float": pa.float64(), "text": pa.string()}


def _optional_ints(values: np.ndarray) -> pa.Array:
    known = ~np.isnan(values)
    return pa.array(np.where(known, values, 0).astype(np.int64), mask=~known)


def _optional_floats(values: np.ndarray) -> pa.Array:
    return pa.array(values, mask=np.isnan(values))


def series_table(series: MeasurementSeries, track: Track | None = None) -> pa.Table:
    """The series as one typed table, a row per time of any of its columns, in time order."""
    track = track if track is not None else run_track(series.run)
    per_column = series_points(series)
    every_time_us = [np.rint(t * 1e6).astype(np.int64) for t, _ in per_column]
    times_us = np.unique(np.concatenate([np.zeros(0, np.int64), *every_time_us]))
    table: dict[str, pa.Array] = {
        "t": pa.array(times_us, UTC_MICROS),
        "t_base": pa.array(times_us + round(series.clock_offset_s * 1e6), UTC_MICROS),
    }
    for name, (times_s, values) in zip(series.columns, per_column, strict=True):
        wide = np.full(len(times_us), np.nan)
        wide[np.searchsorted(times_us, np.rint(times_s * 1e6).astype(np.int64))] = values
        table[name] = _optional_floats(wide)
    placed = place(times_us / 1e6 + series.clock_offset_s, track)
    table["robot_where"] = pa.array([WHERE_NAMES[int(w)] for w in placed.where], pa.string())
    table["robot_track_m"] = _optional_floats(placed.track_m)
    table["robot_unwrapped_m"] = _optional_floats(placed.unwrapped_m)
    table["robot_lap"] = _optional_ints(placed.lap)
    table["robot_segment"] = _optional_ints(placed.segment)
    table["robot_commanded_velocity_mps"] = _optional_floats(placed.commanded_velocity_mps)
    table["robot_velocity_mps"] = _optional_floats(placed.velocity_mps)
    table["robot_lat_deg"] = _optional_floats(placed.lat_deg)
    table["robot_lon_deg"] = _optional_floats(placed.lon_deg)
    table["robot_grid_id"] = pa.array(placed.grid_id, pa.string())
    table["robot_sample_seq"] = _optional_ints(placed.sample_seq)
    return pa.table(table)


def series_schema(series: MeasurementSeries) -> dict[str, Any]:
    """The series table's Table Schema (the CSV's columns, typed, with units)."""
    time_format = {"type": "datetime", "format": CSV_TIME_FORMAT, "unit": "UTC"}
    fields: list[dict[str, Any]] = [
        {"name": "t", **time_format, "description": "when measured, on the measuring clock",
         "constraints": {"required": True}},
        {"name": "t_base", **time_format,
         "description": f"the same on the base station's clock (t + {series.clock_offset_s:g} s)",
         "constraints": {"required": True}},
    ]  # fmt: skip
    for name in series.columns:
        field: dict[str, Any] = {"name": name, "type": "number", "description": series.description}
        if series.unit:
            field["unit"] = series.unit
        fields.append(field)
    for name, _, kind, unit, description in ROBOT_COLUMNS:
        field = {"name": name, "type": kind, "description": description}
        if unit:
            field["unit"] = unit
        if name == "robot_where":
            field["constraints"] = {"required": True, "enum": list(WHERE_NAMES.values())}
        fields.append(field)
    return {
        "fields": fields,
        "primaryKey": ["t"],
        "missingValues": [""],
        "foreignKeys": [
            {"fields": "robot_sample_seq", "reference": {"resource": "samples", "fields": "seq"}}
        ],
    }


def _csv_times(column: pa.ChunkedArray) -> pa.Array:
    micros = column.to_numpy().astype("datetime64[us]")
    return pa.array(np.char.add(np.datetime_as_string(micros, unit="us"), "Z"))


def series_csv(series: MeasurementSeries, track: Track | None = None) -> bytes:
    """The series table as CSV: the header through the portal's one CSV writer, the rows
    by pyarrow (numbers as numbers, an empty cell a missing value)."""
    table = series_table(series, track)
    table = table.set_column(0, "t", _csv_times(table.column("t")))
    table = table.set_column(1, "t_base", _csv_times(table.column("t_base")))
    grid = table.schema.get_field_index("robot_grid_id")
    cells = [None if cell is None else csv_cell(cell) for cell in table.column(grid).to_pylist()]
    table = table.set_column(grid, "robot_grid_id", pa.array(cells, pa.string()))
    head = io.StringIO()
    CsvWriter(head).writerow(table.column_names)
    body = io.BytesIO()
    pa_csv.write_csv(table, body, pa_csv.WriteOptions(include_header=False, quoting_style="needed"))
    return head.getvalue().encode() + body.getvalue()


def parquet_bytes(table: pa.Table, *, metadata: dict[str, str] | None = None) -> bytes:
    """``table`` as a Parquet file (zstd), its ``metadata`` in the file's key-value pairs."""
    if metadata:
        table = table.replace_schema_metadata({**(table.schema.metadata or {}), **metadata})
    out = io.BytesIO()
    pq.write_table(table, out, compression="zstd")
    return out.getvalue()


def samples_table(run: Run, *, columns: Sequence[Any] = SAMPLE_COLUMNS) -> pa.Table:
    """The run's samples as one typed table in ``seq`` order: the contract's columns, ``t`` a
    UTC timestamp, every other column its kind's type, missing values null."""
    names = [column.name for column in columns]
    rows = list(Sample.objects.filter(run=run).order_by("seq").values_list(*names))
    arrays: dict[str, pa.Array] = {}
    for i, column in enumerate(columns):
        values = [row[i] for row in rows]
        if column.kind == "epoch":
            arrays[column.name] = pa.array(values, UTC_MICROS)
        else:
            arrays[column.name] = pa.array(values, _TABLE_TYPES[column.kind])
    return pa.table(arrays)
