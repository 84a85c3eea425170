"""What the base-station agent and the portal agree on, in one Django-free module.

Both sides build from these names instead of restating them: the agent's store, its REST
answers and its run-body checks; the portal's ``Sample`` model (a test compares them), its
ingest, its CSV and JSON downloads, its program validation and its run states. Changing a
column or a limit here changes it everywhere; a side that disagrees fails its tests.

Columns are matched by name, never by position: reordering this tuple only reorders the
downloads.
"""

from __future__ import annotations

import csv
import math
import operator
import re
import uuid
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final, Literal, Protocol

# --- Programs -------------------------------------------------------------------------------

Direction = Literal["cw", "ccw"]
# cw increases the position along the rail (track_m); ccw decreases it.
DIRECTIONS: Final[tuple[Direction, ...]] = ("cw", "ccw")
SEGMENT_FIELDS: Final = ("velocity_mps", "direction", "duration_s")
MAX_SEGMENTS: Final = 100
# A program longer than a day is a mistake, not an experiment: no reservation is that long.
MAX_PROGRAM_S: Final = 24 * 3600.0
MAX_TITLE_CHARS: Final = 200
MAX_OWNER_CHARS: Final = 150


# --- Samples --------------------------------------------------------------------------------

ColumnKind = Literal["int", "float", "text", "epoch"]


def _as_int(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"not an integer: {value!r}")
    return value


def _as_float(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"not a number: {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"not a finite number: {value!r}")
    return number


def _as_text(value: Any) -> str:
    if not isinstance(value, str):
        raise ValueError(f"not a string: {value!r}")
    return value


_CONVERTERS: Final[dict[ColumnKind, Callable[[Any], Any]]] = {
    "int": _as_int,
    "float": _as_float,
    "text": _as_text,
    "epoch": _as_float,
}


# The largest integers the portal's smallint and integer columns store.
INT16_MAX: Final = 2**15 - 1
INT32_MAX: Final = 2**31 - 1


@dataclass(frozen=True)
class SampleColumn:
    """One column of a telemetry sample, as the agent sends it in JSON.

    ``epoch`` is seconds since 1970 (UTC) on the agent's clock; the portal stores it as a
    timestamp. ``max_length`` bounds a text column; ``choices`` lists the values it may take;
    ``minimum`` and ``maximum`` bound a number (an integer column at least to what the
    portal's column stores: nothing may wrap or fail there). ``doc`` is the column's
    description in both APIs' schemas, ``unit`` its unit (SI symbols; empty for a count, a
    code or a text): the downloads' README and data package describe every column by these
    two.
    """

    name: str
    kind: ColumnKind
    nullable: bool = False
    max_length: int | None = None
    choices: tuple[str, ...] | None = None
    minimum: float | None = None
    maximum: float | None = None
    doc: str = ""
    unit: str = ""

    def parse(self, value: Any) -> Any:
        """The JSON ``value`` checked against this column; ``ValueError`` names the column."""
        if value is None:
            if self.nullable:
                return None
            raise ValueError(f"{self.name}: is required")
        try:
            parsed = _CONVERTERS[self.kind](value)
        except ValueError as exc:
            raise ValueError(f"{self.name}: {exc}") from None
        if self.max_length is not None and len(parsed) > self.max_length:
            raise ValueError(f"{self.name}: longer than {self.max_length} characters")
        if self.kind == "text" and not _storable(parsed):
            # No database text holds it: a page with one would fail to store again and again.
            raise ValueError(f"{self.name}: holds a NUL character or a lone surrogate")
        if self.choices is not None and parsed not in self.choices:
            raise ValueError(f"{self.name}: {parsed!r} is not one of {', '.join(self.choices)}")
        if self.minimum is not None and parsed < self.minimum:
            raise ValueError(f"{self.name}: {parsed!r} is less than {self.minimum:g}")
        if self.maximum is not None and parsed > self.maximum:
            raise ValueError(f"{self.name}: {parsed!r} is more than {self.maximum:g}")
        return parsed

    def json_schema(self) -> dict[str, Any]:
        """This column in the agent's JSON, as JSON Schema (``docs/agent-openapi.yaml``)."""
        json_type = {"int": "integer", "float": "number", "text": "string", "epoch": "number"}
        schema: dict[str, Any] = {
            "type": [json_type[self.kind], "null"] if self.nullable else json_type[self.kind]
        }
        if self.choices is not None:
            schema["enum"] = list(self.choices)
        elif self.max_length is not None:
            schema["maxLength"] = self.max_length
        if self.minimum is not None:
            schema["minimum"] = self.minimum
        if self.maximum is not None:
            schema["maximum"] = self.maximum
        doc = f"{self.doc}; epoch seconds, agent clock" if self.kind == "epoch" else self.doc
        if doc:
            schema["description"] = doc
        return schema


SAMPLE_COLUMNS: Final[tuple[SampleColumn, ...]] = (
    SampleColumn(
        "seq",
        "int",
        minimum=1,
        maximum=INT32_MAX,
        doc="sequence number within the run, from 1, no gaps on the agent",
    ),
    SampleColumn("t", "epoch", doc="when the agent recorded it (control tick)", unit="UTC"),
    SampleColumn(
        "segment",
        "int",
        nullable=True,
        minimum=0,
        maximum=INT16_MAX,
        doc="program segment (0-based); null once it is over",
    ),
    SampleColumn("commanded_velocity_mps", "float", doc="what the program asked for", unit="m/s"),
    SampleColumn("velocity_mps", "float", minimum=0, doc="what the robot measured", unit="m/s"),
    SampleColumn("direction", "text", max_length=3, choices=DIRECTIONS, doc="cw or ccw"),
    SampleColumn("battery_v", "float", doc="median-filtered battery voltage", unit="V"),
    SampleColumn(
        "track_m", "float", doc="position along the rail, wraps at rail_length_m", unit="m"
    ),
    SampleColumn(
        "fix_quality",
        "int",
        nullable=True,
        minimum=0,
        maximum=INT16_MAX,
        doc="GPS fix: 0 none, 1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK float; null without a GPS",
    ),
    SampleColumn(
        "lat_deg",
        "float",
        nullable=True,
        doc="latitude (WGS 84); null while the position is unknown",
        unit="°",
    ),
    SampleColumn(
        "lon_deg",
        "float",
        nullable=True,
        doc="longitude (WGS 84); null while the position is unknown",
        unit="°",
    ),
    SampleColumn("grid_id", "text", nullable=True, max_length=8, doc="thesis grid cell, e.g. A2"),
    SampleColumn(
        "lap",
        "int",
        nullable=True,
        minimum=-INT32_MAX,
        maximum=INT32_MAX,
        doc="whole laps since the run started; negative: ccw",
    ),
)
SAMPLE_FIELDS: Final[tuple[str, ...]] = tuple(c.name for c in SAMPLE_COLUMNS)


def sample_json_schema() -> dict[str, Any]:
    """A sample in the agent's JSON, as JSON Schema: what ``docs/agent-openapi.yaml`` says (a
    test compares them). This agent sends every column, null where it has no value; the
    portal also takes a sample without the nullable ones (an older agent: ``sample_parse``)."""
    return {
        "type": "object",
        "additionalProperties": False,
        "required": list(SAMPLE_FIELDS),
        "properties": {c.name: c.json_schema() for c in SAMPLE_COLUMNS},
    }


def sample_parse(raw: Mapping[str, Any]) -> tuple[Any, ...]:
    """One sample from the agent's JSON as a tuple in ``SAMPLE_FIELDS`` order.

    A missing nullable column is None (an older agent); anything else wrong raises
    ``ValueError`` naming the column and the sequence number.
    """
    values = []
    for column in SAMPLE_COLUMNS:
        try:
            values.append(column.parse(raw.get(column.name)))
        except ValueError as exc:
            raise ValueError(f"sample {raw.get('seq')!r}: {exc}") from None
    return tuple(values)


_ACCEPTED_TYPES: Final[dict[ColumnKind, frozenset[type]]] = {
    "int": frozenset({int}),
    "float": frozenset({int, float}),
    "text": frozenset({str}),
    "epoch": frozenset({int, float}),
}


def _storable(text: str) -> bool:
    """Whether a database's text can hold ``text``: no NUL, and valid UTF-8 (a JSON string
    may hold half of a surrogate pair)."""
    if "\x00" in text:
        return False
    try:
        text.encode()
    except UnicodeEncodeError:
        return False
    return True


def _column_plain(column: SampleColumn, values: Sequence[Any]) -> Sequence[Any] | None:
    """``values`` (one column of many samples) each as ``column.parse`` gives it, checked with
    built-ins over the whole column (no Python call per value). None means "look one value at
    a time", not necessarily that a value is wrong (a sum that overflows, an int subclass)."""
    types = set(map(type, values))
    present = values
    if type(None) in types:
        if not column.nullable:
            return None
        types.discard(type(None))
        present = [v for v in values if v is not None]
    if not types <= _ACCEPTED_TYPES[column.kind]:
        return None
    if column.minimum is not None and min(present, default=column.minimum) < column.minimum:
        return None
    if column.maximum is not None and max(present, default=column.maximum) > column.maximum:
        return None
    if column.kind in ("float", "epoch"):
        if int in types:
            try:
                values = [None if v is None else float(v) for v in values]
            except OverflowError:
                return None
            present = [v for v in values if v is not None]
        # NaN or an infinity anywhere makes the sum NaN or infinite.
        return values if math.isfinite(sum(present)) else None
    if column.max_length is not None and max(map(len, present), default=0) > column.max_length:
        return None
    if column.kind == "text" and not _storable("".join(present)):
        return None
    if column.choices is not None and not set(present) <= set(column.choices):
        return None
    return values


_SAMPLE_GETTER: Final = operator.itemgetter(*SAMPLE_FIELDS)


def samples_parse(raws: Sequence[Mapping[str, Any]]) -> list[tuple[Any, ...]]:
    """Many samples from the agent's JSON, each exactly as :func:`sample_parse` gives it.

    A page of thousands is checked a column at a time with built-ins, several times faster
    than one value at a time; a sample without every column (an older agent) or a column
    holding anything unusual sends the page through :func:`sample_parse`, which gives the
    same values and raises the same ``ValueError`` for the first bad sample.
    """
    try:
        rows = list(map(_SAMPLE_GETTER, raws))
    except (KeyError, TypeError):
        return [sample_parse(raw) for raw in raws]
    if not rows:
        return []
    columns = []
    changed = False
    for column, values in zip(SAMPLE_COLUMNS, zip(*rows, strict=True), strict=True):
        checked = _column_plain(column, values)
        if checked is None:
            return [sample_parse(raw) for raw in raws]
        changed = changed or checked is not values
        columns.append(checked)
    return list(zip(*columns, strict=True)) if changed else rows


# --- Run states -----------------------------------------------------------------------------

# On the agent: a run is staged, then running, then ends in one of the end states.
AGENT_STAGED: Final = "staged"
AGENT_RUNNING: Final = "running"
AGENT_COMPLETED: Final = "completed"
AGENT_CANCELLED: Final = "cancelled"
AGENT_ABORTED: Final = "aborted"
AGENT_INTERRUPTED: Final = "interrupted"
AGENT_FAILED: Final = "failed"
AGENT_ACTIVE_STATES: Final = (AGENT_STAGED, AGENT_RUNNING)
AGENT_END_STATES: Final = (
    AGENT_COMPLETED,
    AGENT_CANCELLED,
    AGENT_ABORTED,
    AGENT_INTERRUPTED,
    AGENT_FAILED,
)
AGENT_RUN_STATES: Final = (*AGENT_ACTIVE_STATES, *AGENT_END_STATES)

# How a run's end on the agent ends it in the portal (the portal's ``RunState`` values).
# Aborted (stopped by request, e-stop or low battery) and interrupted (the agent restarted
# mid-run) both keep their partial data there as "interrupted".
PORTAL_STATE_FOR_AGENT_END: Final[Mapping[str, str]] = {
    AGENT_COMPLETED: "completed",
    AGENT_ABORTED: "interrupted",
    AGENT_INTERRUPTED: "interrupted",
    AGENT_CANCELLED: "cancelled",
    AGENT_FAILED: "failed",
}


# --- The emergency stop ---------------------------------------------------------------------

# The agent serves this path ahead of every other request (basestation.serve), and never
# refuses it for its body (basestation.manual.stop_request_from).
STOP_PATH: Final = "/api/v1/stop"


# --- Request ids ----------------------------------------------------------------------------

# One id follows a piece of work across processes: a portal request or task sets it, the
# portal's agent client sends it, the agent logs it in its line for that call.
REQUEST_ID_HEADER: Final = "X-Request-ID"
# Taken from a caller only when it is a plain token: nothing a log reader could trip on.
_REQUEST_ID: Final = re.compile(r"[A-Za-z0-9][A-Za-z0-9._:-]{0,63}")


def new_request_id() -> str:
    return uuid.uuid4().hex


def request_id_or_new(value: str | None) -> str:
    """``value`` when it is a usable request id (letters, digits, ``.``, ``_``, ``:``, ``-``,
    at most 64), else a new one."""
    if value is not None and _REQUEST_ID.fullmatch(value):
        return value
    return new_request_id()


# --- CSV ------------------------------------------------------------------------------------

# A spreadsheet runs a cell that starts with one of these as a formula (=HYPERLINK(…) opens
# a link, DDE calls run commands): a text cell so written gets a leading apostrophe, which
# the spreadsheet shows as text. Numbers are written as numbers (a negative velocity stays
# a number), so only ``str`` cells are looked at.
CSV_FORMULA_PREFIXES: Final = ("=", "+", "-", "@", "\t", "\r")


def csv_cell(value: object) -> object:
    """One cell as every CSV of the portal and the agent writes it: None empty, a text that
    a spreadsheet would take for a formula escaped, anything else as it is."""
    if value is None:
        return ""
    if isinstance(value, str) and value.startswith(CSV_FORMULA_PREFIXES):
        return "'" + value
    return value


class _Writable(Protocol):
    def write(self, text: str, /) -> Any: ...


class CsvWriter:
    """The one CSV writer of the portal and the agent (``csv.writer`` with ``csv_cell`` on
    every cell). The one CSV it does not write, the samples that PostgreSQL's ``COPY … CSV``
    writes, escapes its text columns the same way in SQL (``portal/runs/selectors.py``)."""

    def __init__(self, stream: _Writable) -> None:
        # RFC 4180's CRLF: a cell holding a CR or an LF is quoted (with LF alone as the line
        # end, a CR in a title went out bare and began a new row in a spreadsheet).
        self._writer = csv.writer(stream, lineterminator="\r\n")

    def writerow(self, row: Iterable[object]) -> None:
        self._writer.writerow([csv_cell(value) for value in row])

    def writerows(self, rows: Iterable[Iterable[object]]) -> None:
        for row in rows:
            self.writerow(row)
