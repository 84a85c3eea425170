from django.db import migrations
from django.db.models import Max


def _mail_from_now_on(apps, schema_editor):  # type: ignore[no-untyped-def]
    # The reservation e-mails of the events already written were sent the old way: the new
    # handler starts after them, not at the first event.
    event = apps.get_model("events", "Event")
    cursor = apps.get_model("events", "EventCursor")
    last = event.objects.aggregate(last=Max("position"))["last"] or 0
    cursor.objects.get_or_create(handler="reservation-mail", defaults={"position": last})


class Migration(migrations.Migration):
    """The e-mails about a reservation are a reaction to its events now
    (``bookings/handlers.py``), the reminder one too (``reservation.starting_soon``, once per
    reservation), so ``reminder_sent_at`` leaves the model; its column stays, nullable, while
    the previous release may still run during an upgrade, and goes in a later release."""

    dependencies = [
        ("bookings", "0013_resource_hold_notified_at_unused"),
        ("events", "0002_event_once_per_subject"),
    ]

    operations = [
        migrations.SeparateDatabaseAndState(
            state_operations=[
                migrations.RemoveField(model_name="reservation", name="reminder_sent_at")
            ],
            database_operations=[],
        ),
        migrations.RunPython(_mail_from_now_on, migrations.RunPython.noop),
    ]
