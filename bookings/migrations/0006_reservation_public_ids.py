"""Every existing reservation gets its own public id (one uuid4 each, not a shared default)."""

import uuid

from django.db import migrations


def fill(apps, schema_editor):
    reservation = apps.get_model("bookings", "Reservation")
    db = schema_editor.connection.alias
    for pk in (
        reservation.objects.using(db).filter(public_id__isnull=True).values_list("pk", flat=True)
    ):
        reservation.objects.using(db).filter(pk=pk).update(public_id=uuid.uuid4())


class Migration(migrations.Migration):
    dependencies = [("bookings", "0005_scheduler_mirror")]

    operations = [migrations.RunPython(fill, migrations.RunPython.noop)]
