"""The booking rules on SQLite, the embedded default of ``make run``.

The suite runs on PostgreSQL; this runs the same services in a child process on a fresh
SQLite file, where the locked checks are the only guard (no exclusion constraint).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

SCRIPT = r"""
import django
django.setup()
from datetime import timedelta
from django.core.management import call_command
from django.utils import timezone
call_command("migrate", verbosity=0)
from bookings.models import QuotaPolicy, Resource
from bookings.services import blackout_create, reservation_cancel, reservation_create
from portal.accounts.models import User
from portal.errors import Conflict

node = Resource.objects.create(name="node-01", kind="fixed")
alice = User.objects.create_user("alice")
bob = User.objects.create_user("bob")
admin = User.objects.create_user("admin", is_staff=True)
start = timezone.now() + timedelta(days=1)
hour = timedelta(hours=1)
first = reservation_create(owner=alice, resource=node, start_at=start, end_at=start + hour)
try:
    half = start + hour / 2
    reservation_create(owner=bob, resource=node, start_at=half, end_at=half + hour)
except Conflict as exc:
    print("refused:", exc.message)
blackout_create(
    by=admin, start_at=start + 3 * hour, end_at=start + 4 * hour, reason="mast", resources=[node]
)
try:
    reservation_create(owner=bob, resource=node, start_at=start + 3 * hour, end_at=start + 4 * hour)
except Conflict as exc:
    print("refused:", exc.message)
QuotaPolicy.objects.create(name="one a day", user=bob, period="day", max_count=1)
reservation_create(owner=bob, resource=node, start_at=start + 5 * hour, end_at=start + 6 * hour)
try:
    reservation_create(owner=bob, resource=node, start_at=start + 7 * hour, end_at=start + 8 * hour)
except Conflict as exc:
    print("refused:", exc.message)
reservation_cancel(reservation=first, by=alice)  # frees the slot again
reservation_create(owner=bob, resource=node, start_at=start, end_at=start + hour, by=admin)
print("vendor:", django.db.connection.vendor)
"""


def test_booking_rules_hold_on_sqlite(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in {"DATABASE_URL", "CELERY_BROKER_URL"}}
    env.update({"DJANGO_SETTINGS_MODULE": "portal.settings", "DJANGO_DEBUG": "1",
                "AMAZING_VAR_DIR": str(tmp_path)})  # fmt: skip
    result = subprocess.run(
        [sys.executable, "-c", SCRIPT], cwd=REPO, env=env, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    lines = [
        line for line in result.stdout.splitlines() if line.startswith(("refused:", "vendor:"))
    ]
    assert lines[0].startswith("refused: node-01 is already booked from")
    assert lines[1].startswith("refused: Maintenance “mast”")
    assert lines[2].startswith("refused: “one a day” allows 1 reservation per day")
    assert lines[3] == "vendor: sqlite"
