"""Runs moved from the experiments app to the runs app keep their rows, history and samples."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from django.db import connection
from django.db.migrations.executor import MigrationExecutor

from portal.runs.models import Run, RunEvent, Sample

# The whole schema as it was before the move (bookings too: its later columns are not null).
BEFORE = [
    ("experiments", "0003_run_rail_length"),
    ("runs", None),
    ("bookings", "0004_agent_url_bare_host_names"),
]


def _migrate(targets):
    executor = MigrationExecutor(connection)
    executor.loader.build_graph()
    executor.migrate(targets)
    return executor.loader.project_state([t for t in targets if t[1] is not None]).apps


def _latest():
    return MigrationExecutor(connection).loader.graph.leaf_nodes()


@pytest.fixture
def before_the_move():
    """The database as it was before the move; every migration is applied again after."""
    try:
        yield _migrate(BEFORE)
    finally:
        _migrate(_latest())


@pytest.mark.django_db(transaction=True)
def test_runs_and_their_samples_survive_the_move(before_the_move):
    old = before_the_move
    user = old.get_model("accounts", "User").objects.create(username="alice")
    resource = old.get_model("bookings", "Resource").objects.create(
        name="mobile-1", kind="mobile", max_velocity_mps=2.0, max_accel_mps2=1.0
    )
    start = datetime(2030, 1, 1, 10, tzinfo=UTC)
    reservation = old.get_model("bookings", "Reservation").objects.create(
        owner=user, start_at=start, end_at=start + timedelta(hours=1)
    )
    experiment = old.get_model("experiments", "Experiment").objects.create(
        owner=user, title="laps", segments=[]
    )
    run = old.get_model("experiments", "Run").objects.create(
        reservation=reservation,
        resource=resource,
        experiment=experiment,
        title="laps",
        segments=[],
        start_at=start,
        end_at=start + timedelta(hours=1),
        state="completed",
        last_seq=2,
    )
    old.get_model("experiments", "RunEvent").objects.create(run=run, to_state="completed")
    for seq in (1, 2):
        old.get_model("experiments", "Sample").objects.create(
            run=run,
            seq=seq,
            t=start,
            commanded_velocity_mps=0.5,
            velocity_mps=0.5,
            direction="cw",
            battery_v=60.0,
            track_m=float(seq),
        )

    _migrate(_latest())

    moved = Run.objects.get(pk=run.pk)
    assert (moved.title, moved.state, moved.last_seq) == ("laps", "completed", 2)
    assert list(Sample.objects.filter(run=moved).values_list("seq", flat=True)) == [1, 2]
    assert RunEvent.objects.filter(run=moved).count() == 1
    assert Run._meta.db_table == "runs_run"
    # New rows keep counting after the moved ones (the id sequence moved with the table).
    newest = Sample.objects.create(
        run=moved,
        seq=3,
        t=start,
        commanded_velocity_mps=0.5,
        velocity_mps=0.5,
        direction="cw",
        battery_v=60.0,
        track_m=3.0,
    )
    assert newest.pk > max(Sample.objects.filter(seq__lt=3).values_list("pk", flat=True))
    tables = connection.introspection.table_names()
    assert "runs_sample" in tables
    assert "experiments_sample" not in tables
