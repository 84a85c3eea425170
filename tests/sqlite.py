"""Run a script against a fresh SQLite database: the embedded default of ``make run``.

The suite runs on PostgreSQL; code with a database-specific path is also run this way, in a
child process whose settings have no DATABASE_URL.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

PRELUDE = """
import django
django.setup()
from django.core.management import call_command
call_command("migrate", verbosity=0)
"""


def run_on_sqlite(script: str, var_dir: Path) -> list[str]:
    """The script's standard output lines, after asserting it ran on SQLite and exited 0."""
    env = {k: v for k, v in os.environ.items() if k not in {"DATABASE_URL", "CELERY_BROKER_URL"}}
    env.update({"DJANGO_SETTINGS_MODULE": "portal.settings", "DJANGO_DEBUG": "1",
                "AMAZING_VAR_DIR": str(var_dir)})  # fmt: skip
    script = PRELUDE + script + '\nprint("vendor:", django.db.connection.vendor)\n'
    result = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, env=env, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    lines = result.stdout.splitlines()
    assert "vendor: sqlite" in lines
    return lines
