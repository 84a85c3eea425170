from django.db import migrations


class Migration(migrations.Migration):
    """The owner's mail about a failed or interrupted run is a reaction to its event now
    (``portal/runs/handlers.py``), which needs no mark. The field leaves the model; its column
    stays, nullable, while the previous release may still run during an upgrade, and goes in a
    later release."""

    dependencies = [("runs", "0006_dry_run")]

    operations = [
        migrations.SeparateDatabaseAndState(
            state_operations=[migrations.RemoveField(model_name="run", name="owner_told_at")],
            database_operations=[],
        ),
    ]
