"""The booking rules on SQLite, the embedded default of ``make run``.

The suite runs on PostgreSQL; this runs the same services in a child process on a fresh
SQLite file, where the locked checks are the only guard (no exclusion constraint).
"""

from __future__ import annotations

from tests.sqlite import run_on_sqlite

SCRIPT = r"""
from datetime import datetime, time, timedelta
from django.utils import timezone
from bookings.models import QuotaPolicy, Resource
from bookings.services import blackout_create, reservation_cancel, reservation_create
from core.accounts.models import User
from core.errors import Conflict

node = Resource.objects.create(name="node-01", kind="fixed")
alice = User.objects.create_user("alice")
bob = User.objects.create_user("bob")
admin = User.objects.create_user("admin", is_staff=True)
# The services are called directly: marked as a door that checked the second factor marks it.
admin.staff_verified = True
# 08:00 the day after tomorrow: every booking below falls on one local day, whatever the
# time the test runs at (the "one a day" quota depends on it).
day = (timezone.localtime() + timedelta(days=2)).date()
start = timezone.make_aware(datetime.combine(day, time(8)))
hour = timedelta(hours=1)
first = reservation_create(owner=alice, resource=node, start_at=start, end_at=start + hour)
try:
    half = start + hour / 2
    reservation_create(owner=bob, resource=node, start_at=half, end_at=half + hour)
except Conflict as exc:
    print("refused:", exc.message)
# Back to back is no overlap: the hour after alice's is free.
after = reservation_create(
    owner=alice, resource=node, start_at=start + hour, end_at=start + 2 * hour
)
print("back to back:", after.start_at == first.end_at)
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
try:
    reservation_create(owner=bob, resource=node, start_at=start, end_at=start + hour, by=admin)
except Conflict as exc:
    print("refused:", exc.message)
booked = reservation_create(owner=bob, resource=node, start_at=start, end_at=start + hour,
                            by=admin, override_reason="calibration")
print("override:", booked.override_reason)
"""


def test_booking_rules_hold_on_sqlite(tmp_path):
    output = run_on_sqlite(SCRIPT, tmp_path)
    assert "override: calibration" in output
    assert "back to back: True" in output
    lines = [line for line in output if line.startswith("refused:")]
    assert lines[0].startswith("refused: node-01 is already booked from")
    assert lines[1].startswith("refused: Maintenance “mast”")
    assert lines[2].startswith("refused: “one a day” allows 1 reservation per day")
    # An admin booking for bob is held to bob's quota, unless the admin overrides it.
    assert lines[3].startswith("refused: “one a day” allows 1 reservation per day")
    assert len(lines) == 4
