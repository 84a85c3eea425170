"""Every hand-written query answers alike on SQLite and on PostgreSQL.

The suite runs on PostgreSQL. :func:`scenario` calls every query of ``bookings/queries.py``
and ``portal/runs/queries.py`` on a small testbed, here (PostgreSQL) and in a child process on
a fresh SQLite file (``tests/sqlite.py``), and records which query functions ran. A query that
is PostgreSQL's alone (``core.sql.postgresql_only``: ``COPY``, arrays) is reached through its
caller, whose other path runs on SQLite: the answers must be the same. A new query that the
scenario does not run fails here.
"""

from __future__ import annotations

import csv
import importlib
import inspect
import io
import json
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
from django.db import transaction

from bookings import queries as bookings_queries
from bookings.choices import (
    RESERVATION_ACTIVE_STATES,
    RESERVATION_COUNTED_STATES,
    ReservationState,
)
from bookings.models import (
    Blackout,
    QuotaPolicy,
    Reservation,
    ReservationItem,
    Resource,
    ResourceGroup,
)
from core import sql
from core.accounts.models import User
from portal.experiments.models import Experiment
from portal.runs import queries as runs_queries
from portal.runs.measurements import measurement_add, read_file_points, series_points
from portal.runs.models import MeasurementSeries, Run, Sample
from portal.runs.selectors import run_samples_csv, run_samples_json
from portal.runs.services.collection import samples_ingest
from tests.sqlite import run_on_sqlite

QUERY_MODULES = ("bookings.queries", "portal.runs.queries")
DAY = datetime(2031, 3, 3, tzinfo=UTC)  # every instant is fixed: nothing here reads the clock
HOUR = timedelta(hours=1)
T0_S = datetime(2031, 3, 4, 10, tzinfo=UTC).timestamp()
GRID_IDS = ['a"b', "c\\d", "=1+1", None]  # quotes, a backslash, a spreadsheet formula


def public_queries() -> dict[str, Callable[..., Any]]:
    """Every public function of the query modules, by ``module.name``."""
    found: dict[str, Callable[..., Any]] = {}
    for module_name in QUERY_MODULES:
        module = importlib.import_module(module_name)
        for name, value in vars(module).items():
            if (
                inspect.isfunction(value)
                and value.__module__ == module_name
                and not name.startswith("_")
            ):
                found[f"{module_name}.{name}"] = value
    return found


@contextmanager
def recorded() -> Iterator[set[str]]:
    """Which query functions are called meanwhile (the callers look them up on their module
    at each call: ``queries.conflicts(…)``)."""
    called: set[str] = set()
    originals = public_queries()

    def spy(qualified: str, function: Callable[..., Any]) -> Callable[..., Any]:
        def call(*args: Any, **kwargs: Any) -> Any:
            called.add(qualified)
            return function(*args, **kwargs)

        return call

    modules = {name: importlib.import_module(name) for name in QUERY_MODULES}
    for qualified, function in originals.items():
        module_name, name = qualified.rsplit(".", 1)
        setattr(modules[module_name], name, spy(qualified, function))
    try:
        yield called
    finally:
        for qualified, function in originals.items():
            module_name, name = qualified.rsplit(".", 1)
            setattr(modules[module_name], name, function)


def _samples(first_seq: int, last_seq: int) -> list[dict[str, Any]]:
    return [
        {"seq": seq, "t": T0_S + 0.5 * seq + (1e-6 if seq % 3 == 0 else 0.0),
         "segment": 0 if seq % 2 else None, "commanded_velocity_mps": 1.0,
         "velocity_mps": 0.25 * seq, "direction": "ccw" if seq % 2 else "cw",
         "battery_v": 60.0, "track_m": 0.1 * seq, "fix_quality": None if seq % 2 else 4,
         "lat_deg": 40.6343, "lon_deg": None, "grid_id": GRID_IDS[seq % len(GRID_IDS)],
         "lap": -seq}
        for seq in range(first_seq, last_seq + 1)
    ]  # fmt: skip


def _number_or_text(cell: str) -> float | str | None:
    """A CSV cell as a number where it is one: PostgreSQL writes 1 where Python writes 1.0."""
    if cell == "":
        return None
    try:
        return float(cell)
    except ValueError:
        return cell


def _column(values: list[float]) -> list[float | None]:
    """A report column as JSON carries it: NaN as None, times to the millisecond (SQLite's
    julianday holds an instant to some tens of microseconds)."""
    return [None if math.isnan(v) else round(v, 3) for v in values]


def _bookings_answers() -> dict[str, Any]:
    """The bookings' queries on a day of bookings and maintenance; ids as labels, since each
    database numbers rows its own way."""
    alice = User.objects.create_user("q-alice")
    bob = User.objects.create_user("q-bob")
    node1 = Resource.objects.create(name="q-node-1", kind="fixed")
    node2 = Resource.objects.create(name="q-node-2", kind="fixed")
    north = ResourceGroup.objects.create(name="q-north")
    node2.groups.add(north)
    labels: dict[tuple[str, int], str] = {}
    booked: dict[str, Reservation] = {}

    def book(label: str, owner: User, nodes: list[Resource], start_h: float, end_h: float,
             state: str = ReservationState.CONFIRMED) -> None:  # fmt: skip
        start, end = DAY + start_h * HOUR, DAY + end_h * HOUR
        reservation = Reservation.objects.create(
            owner=owner, start_at=start, end_at=end, state=state
        )
        booked[label] = reservation
        for node in nodes:
            item = ReservationItem.objects.create(
                reservation=reservation, resource=node, start_at=start, end_at=end,
                active=state in RESERVATION_ACTIVE_STATES,
            )  # fmt: skip
            labels["booked", item.pk] = f"{label} {node.name}"

    book("early", alice, [node1], -1, 1)  # from the day before
    book("R1", alice, [node1], 9, 10)
    book("R2", alice, [node2], 11, 12, ReservationState.REQUESTED)
    book("R3", alice, [node1, node2], 14, 16)
    book("R4", alice, [node1], 9.5, 10.5, ReservationState.CANCELLED)
    book("R5", alice, [node1], 20, 21, ReservationState.COMPLETED)
    book("B1", bob, [node2], 8.5, 9.5)
    mast = Blackout.objects.create(
        start_at=DAY + 9.5 * HOUR, end_at=DAY + 10.5 * HOUR, reason="mast"
    )
    mast.resources.add(node2)
    roof = Blackout.objects.create(
        start_at=DAY + 17 * HOUR, end_at=DAY + 18 * HOUR, reason="roof", all_resources=True
    )
    labels["blackout", mast.pk] = "mast"
    labels["blackout", roof.pk] = "roof"

    def conflicts(nodes: list[Resource], start_h: float, end_h: float, **options: Any) -> list:
        found = bookings_queries.conflicts(
            [n.pk for n in nodes], DAY + start_h * HOUR, DAY + end_h * HOUR, **options
        )
        return [labels[kind, pk] for kind, pk in found]

    everyone = QuotaPolicy.objects.create(name="q-all", user=alice)
    on_node1 = QuotaPolicy.objects.create(name="q-node-1", resource=node1)
    in_north = QuotaPolicy.objects.create(name="q-north", resource_group=north)
    day_end = DAY + 24 * HOUR

    def periods(policy: QuotaPolicy, **options: Any) -> list[list[str]]:
        read = bookings_queries.quota_periods(
            policy, alice, RESERVATION_COUNTED_STATES, DAY, day_end, **options
        )
        return sorted([start.isoformat(), end.isoformat()] for start, end in read)

    upcoming_states = [s for s in RESERVATION_COUNTED_STATES if s in RESERVATION_ACTIVE_STATES]
    now = DAY + 10.5 * HOUR

    def upcoming(policy: QuotaPolicy, **options: Any) -> int:
        return bookings_queries.quota_upcoming(policy, alice, upcoming_states, now=now, **options)

    with transaction.atomic():
        locked = bookings_queries.resources_locked(alice.pk, [node2.pk, node1.pk, node2.pk])
    return {
        "conflicts": conflicts([node1, node2], 9, 11),
        "conflicts, first only": conflicts([node1, node2], 9, 11, first_only=True),
        "conflicts, R1 moved": conflicts([node1], 9, 11, exclude_reservation_id=booked["R1"].pk),
        "conflicts, back to back": conflicts([node1], 10, 11),
        "conflicts, all resources": conflicts([node2], 17.5, 17.75),
        "locked": [r.name for r in locked],
        "periods, user": periods(everyone),
        "periods, resource": periods(on_node1),
        "periods, resource group": periods(in_north),
        "periods, resource group, R3 moved": periods(in_north, exclude_id=booked["R3"].pk),
        "upcoming, user": upcoming(everyone),
        "upcoming, resource": upcoming(on_node1),
        "upcoming, resource group": upcoming(in_north),
        "upcoming, resource group, R3 moved": upcoming(in_north, exclude_id=booked["R3"].pk),
    }


def _runs_answers() -> dict[str, Any]:
    """A run's samples in (a new page, an overlapping one, one sent again) and out."""
    owner = User.objects.create_user("q-carol")
    robot = Resource.objects.create(name="q-mobile", kind="mobile")
    segments = [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 3.0}]
    experiment = Experiment.objects.create(owner=owner, title="q", segments=segments)
    start = datetime.fromtimestamp(T0_S, UTC)
    reservation = Reservation.objects.create(owner=owner, start_at=start, end_at=start + HOUR)
    run = Run.objects.create(
        reservation=reservation, resource=robot, experiment=experiment, title="q",
        segments=segments, start_at=start, end_at=start + HOUR,
    )  # fmt: skip
    stored = [
        samples_ingest(run=run, samples=_samples(1, 4)),
        samples_ingest(run=run, samples=_samples(3, 6)),
        samples_ingest(run=run, samples=_samples(1, 6)),
    ]
    text = b"".join(run_samples_csv(run=run)).decode()
    document = json.loads(b"".join(run_samples_json(run=run)))
    columns = runs_queries.sample_columns(run)
    return {
        "measurements": _measurement_answers(run, owner),
        "stored": stored,
        "seqs": list(Sample.objects.filter(run=run).order_by("seq").values_list("seq", flat=True)),
        "csv": [
            [_number_or_text(cell) for cell in row]
            for row in csv.reader(io.StringIO(text, newline=""))
        ],
        "json": document["samples"],
        "columns": {
            name: _column(getattr(columns, name).astype(float).tolist())
            for name in ("seq", "t_s", "segment", "ccw", "track_m", "fix_quality")
        },
    }


def _measurement_answers(run: Run, owner: User) -> dict[str, Any]:
    """A series's points in (new ones, overlapping ones, the first again) and out."""

    def points(first: int, last: int) -> Any:
        rows = "".join(f"{T0_S + i * 0.5},{-50 - i}\n" for i in range(first, last + 1))
        return read_file_points(f"t,rssi\n{rows}".encode(), "csv")

    stored = [
        measurement_add(run=run, by=owner, name="rssi", points=batch).stored
        for batch in (points(0, 5), points(4, 7), points(0, 5))
    ]
    series = MeasurementSeries.objects.get(run=run, name="rssi")
    ((times_s, values),) = series_points(series)
    return {
        "stored": stored,
        "times_s": [round(t - T0_S, 3) for t in times_s.tolist()],
        "values": values.tolist(),
        "where": series.summary["columns"]["rssi"]["where"],
    }


def scenario() -> dict[str, Any]:
    """The answers of every query, and which query functions ran."""
    with recorded() as called:
        answers = {"bookings": _bookings_answers(), "runs": _runs_answers()}
    sql.ping()
    sql.advisory_xact_lock(1)
    answers["core"] = {"lock taken": sql.try_advisory_xact_lock(2)}
    return {"answers": answers, "called": sorted(called)}


def _expected_rows() -> list[dict[str, Any]]:
    """The samples as the downloads give them: times in UTC with six digits and Z."""
    rows = []
    for sample in _samples(1, 6):
        t = datetime.fromtimestamp(sample["t"], UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        rows.append({**sample, "t": t})
    return rows


def _check_answers(answers: dict[str, Any]) -> None:
    """What each query must say of the scenario, whichever database answered."""
    bookings = answers["bookings"]
    assert bookings["conflicts"] == ["mast", "B1 q-node-2", "R1 q-node-1"]
    assert bookings["conflicts, first only"] == ["mast"]
    assert bookings["conflicts, R1 moved"] == []  # R4 was cancelled, the mast is node 2's
    assert bookings["conflicts, back to back"] == []
    assert bookings["conflicts, all resources"] == ["roof"]
    assert bookings["locked"] == ["q-node-1", "q-node-2"]

    def at(hours: float) -> str:
        return (DAY + hours * HOUR).isoformat()

    early, r1, r2, r3, r5 = ([at(s), at(e)] for s, e in ((-1, 1), (9, 10), (11, 12),
                                                          (14, 16), (20, 21)))  # fmt: skip
    # R4 was cancelled; R5, completed, still counts.
    assert bookings["periods, user"] == [early, r1, r2, r3, r5]
    assert bookings["periods, resource"] == [early, r1, r3, r5]
    assert bookings["periods, resource group"] == [r2, r3]
    assert bookings["periods, resource group, R3 moved"] == [r2]
    # At 10:30, R2 and R3 are still to come; R5 is completed, not upcoming.
    assert bookings["upcoming, user"] == 2
    assert bookings["upcoming, resource"] == 1
    assert bookings["upcoming, resource group"] == 2
    assert bookings["upcoming, resource group, R3 moved"] == 1

    runs = answers["runs"]
    assert runs["stored"] == [4, 2, 0]
    assert runs["seqs"] == [1, 2, 3, 4, 5, 6]
    expected = _expected_rows()
    assert runs["json"] == expected
    header, *rows = runs["csv"]
    assert header == list(expected[0])
    formula = {'a"b': 'a"b', "c\\d": "c\\d", "=1+1": "'=1+1", None: None}
    assert rows == [
        [_number_or_text(str(v)) if isinstance(v, float | int) else v for v in
         {**row, "grid_id": formula[row["grid_id"]]}.values()]
        for row in expected
    ]  # fmt: skip
    columns = runs["columns"]
    assert columns["seq"] == [1, 2, 3, 4, 5, 6]
    assert columns["t_s"] == [round(s["t"], 3) for s in _samples(1, 6)]
    assert columns["segment"] == [0, None, 0, None, 0, None]
    assert columns["ccw"] == [1, 0, 1, 0, 1, 0]
    assert columns["fix_quality"] == [None, 4, None, 4, None, 4]
    measured = runs["measurements"]
    assert measured["stored"] == [6, 2, 0]
    assert measured["times_s"] == [0.5 * i for i in range(8)]
    assert measured["values"] == [-50.0 - i for i in range(8)]
    assert sum(measured["where"].values()) == 8
    assert answers["core"] == {"lock taken": True}


@pytest.mark.django_db
def test_every_query_answers_alike_on_sqlite_and_postgresql(tmp_path):
    queries = public_queries()
    postgresql_only = {name for name, f in queries.items() if getattr(f, "postgresql_only", 0)}
    assert postgresql_only  # COPY and arrays

    here = scenario()
    lines = run_on_sqlite(
        "import json\nfrom tests.test_queries_sqlite import scenario\n"
        "print('scenario:', json.dumps(scenario()))",
        tmp_path,
    )
    on_sqlite = json.loads(next(line for line in lines if line.startswith("scenario:"))[9:])

    _check_answers(here["answers"])
    _check_answers(on_sqlite["answers"])
    assert on_sqlite["answers"] == json.loads(json.dumps(here["answers"]))
    # Every query ran on PostgreSQL; on SQLite all but PostgreSQL's own, whose callers took
    # their other path above and gave the same answers.
    assert here["called"] == sorted(queries), "run each new query in scenario()"
    assert on_sqlite["called"] == sorted(set(queries) - postgresql_only), (
        "on SQLite a query runs unless it is sql.postgresql_only, and then never"
    )
