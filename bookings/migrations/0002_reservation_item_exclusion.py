"""No two active holdings of one resource may overlap: enforced by PostgreSQL itself.

SQLite (the embedded default) has no exclusion constraints; there the services' locked
check is the only guard.
"""

from django.db import migrations

CONSTRAINT = "reservation_item_no_overlap"

CREATE = f"""
CREATE EXTENSION IF NOT EXISTS btree_gist;
ALTER TABLE bookings_reservationitem ADD CONSTRAINT {CONSTRAINT}
    EXCLUDE USING gist (resource_id WITH =, tstzrange(start_at, end_at, '[)') WITH &&)
    WHERE (active);
"""
DROP = f"ALTER TABLE bookings_reservationitem DROP CONSTRAINT IF EXISTS {CONSTRAINT};"


def forwards(apps, schema_editor):
    if schema_editor.connection.vendor == "postgresql":
        schema_editor.execute(CREATE)


def backwards(apps, schema_editor):
    if schema_editor.connection.vendor == "postgresql":
        schema_editor.execute(DROP)


class Migration(migrations.Migration):
    dependencies = [("bookings", "0001_initial")]
    operations = [migrations.RunPython(forwards, backwards)]
