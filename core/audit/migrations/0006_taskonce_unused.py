from django.db import migrations


class Migration(migrations.Migration):
    """A side effect done once is a reaction to an event now (``core.events``): its handler's
    cursor moves in the transaction of the effect. ``TaskOnce`` leaves the models; its table
    stays while the previous release may still run during an upgrade, and goes in a later
    release."""

    dependencies = [("audit", "0005_event_count")]

    operations = [
        migrations.SeparateDatabaseAndState(
            state_operations=[migrations.DeleteModel(name="TaskOnce")],
            database_operations=[],
        ),
    ]
