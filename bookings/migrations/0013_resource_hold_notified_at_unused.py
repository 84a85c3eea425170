from django.db import migrations


class Migration(migrations.Migration):
    """The admins' mail about a hold is a reaction to the ``robot.held`` event now
    (``portal/runs/handlers.py``), which needs no mark. The field leaves the model; its column
    stays, nullable, while the previous release may still run during an upgrade, and goes in a
    later release."""

    dependencies = [("bookings", "0012_calendar_feed_token_digest")]

    operations = [
        migrations.SeparateDatabaseAndState(
            state_operations=[
                migrations.RemoveField(model_name="resource", name="hold_notified_at")
            ],
            database_operations=[],
        ),
    ]
