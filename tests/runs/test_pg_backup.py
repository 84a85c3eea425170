"""The PostgreSQL backup of docs/operations.md: ``pg_dump -Fc``, then ``pg_restore`` into a
fresh, empty database, which holds every run and every sample of the original."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import psycopg
import pytest
from django.db import connection

from core.audit.models import AuditEvent
from portal.runs.models import Run, RunEvent, Sample
from tests.factories import MobileResourceFactory, UserFactory
from tests.runs.driving import completed_run

pytestmark = pytest.mark.django_db(transaction=True)


def _conninfo(name: str) -> str:
    db = connection.settings_dict
    return f"host={db['HOST']} port={db['PORT']} user={db['USER']} dbname={name}"


def _pg(*argv: str) -> None:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr


@pytest.fixture
def fresh_database() -> Iterator[str]:
    name = f"{connection.settings_dict['NAME']}_restored"
    db = connection.settings_dict
    where = ["-h", db["HOST"], "-p", str(db["PORT"]), "-U", db["USER"]]
    _pg("dropdb", *where, "--if-exists", name)
    _pg("createdb", *where, name)
    try:
        yield name
    finally:
        _pg("dropdb", *where, "--if-exists", "--force", name)


def _rows(name: str, table: str, order: str) -> list[tuple[object, ...]]:
    with psycopg.connect(_conninfo(name)) as conn:
        return conn.execute(f"SELECT * FROM {table} ORDER BY {order}").fetchall()  # noqa: S608


def test_a_dump_restored_into_a_fresh_database_holds_every_run_and_sample(
    tmp_path: Path, fresh_database: str
):
    owner = UserFactory()
    robots = [MobileResourceFactory(name="mobile-1"), MobileResourceFactory(name="mobile-2")]
    for robot in robots:
        completed_run(owner, robot, [(0.5, "cw", 20.0), (0.8, "ccw", 10.0)])
    assert Sample.objects.count() > 1000
    source = connection.settings_dict["NAME"]
    db = connection.settings_dict
    where = ["-h", db["HOST"], "-p", str(db["PORT"]), "-U", db["USER"]]
    dump = tmp_path / "amazing.dump"

    _pg("pg_dump", *where, "--format=custom", f"--file={dump}", source)
    _pg("pg_restore", *where, "--no-owner", "--exit-on-error", f"--dbname={fresh_database}", dump)

    for model, order in ((Run, "id"), (Sample, "run_id, seq"), (RunEvent, "id")):
        table = model._meta.db_table
        original = _rows(source, table, order)
        assert original, table
        assert _rows(fresh_database, table, order) == original, table
    # The audit log comes back with its append-only rule (a trigger in the schema).
    audit = AuditEvent._meta.db_table
    assert _rows(fresh_database, audit, "id") == _rows(source, audit, "id") != []
    with psycopg.connect(_conninfo(fresh_database)) as conn, pytest.raises(psycopg.Error):
        conn.execute(f"DELETE FROM {audit}")  # noqa: S608
