"""The shared modules moved from ``portal/`` to ``core/`` with their app labels, tables and
migrations: a database made before the move migrates and its rows are found."""

from __future__ import annotations

import os
import re
import sqlite3
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
# A SQLite database made with the code before the move (accounts, audit and every other app
# migrated; one user, one audit event), as SQL text.
BEFORE = REPO / "tests" / "data" / "before_core_move.sql"

CHECK = """
import django
django.setup()
from django.contrib.contenttypes.models import ContentType
from core.accounts.models import User
from core.audit.models import AuditEvent
user = User.objects.get(username="ada")
event = AuditEvent.objects.get(action="demo.before_move")
assert event.actor_id == user.pk, event.actor_id
assert ContentType.objects.get_for_model(User).app_label == "accounts"
assert User._meta.db_table == "accounts_user"
print("found", user.email, event.reason)
"""


def _manage_env(var_dir: Path) -> dict[str, str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("DATABASE_", "CELERY_", "REDIS_", "DJANGO_"))
    }
    env.update(
        {
            "DJANGO_DEBUG": "1",
            "AMAZING_VAR_DIR": str(var_dir),
            "DJANGO_SETTINGS_MODULE": "portal.settings",
        }
    )
    return env


def test_a_database_made_before_the_move_migrates_and_keeps_its_rows(tmp_path):
    with sqlite3.connect(tmp_path / "portal.sqlite3") as db:
        db.executescript(BEFORE.read_text())
    env = _manage_env(tmp_path)
    migrate = subprocess.run(
        [sys.executable, "manage.py", "migrate", "--no-input"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert migrate.returncode == 0, migrate.stdout + migrate.stderr
    # No migration the old database recorded is applied again (accounts and audit keep their
    # labels and migrations); only the ones written since are.
    recorded = set(re.findall(r"'(\w+)','(\w+)','", BEFORE.read_text()))
    applied = set(re.findall(r"Applying (\w+)\.(\w+)\.\.\.", migrate.stdout))
    assert ("accounts", "0001_initial") in recorded
    assert ("audit", "0001_initial") in recorded
    assert not recorded & applied, recorded & applied
    found = subprocess.run(
        [sys.executable, "-c", CHECK],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert found.returncode == 0, found.stderr
    assert found.stdout.strip() == "found ada@example.org made before the shared modules moved"
