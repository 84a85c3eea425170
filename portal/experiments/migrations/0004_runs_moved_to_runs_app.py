"""Run, RunEvent and Sample now belong to the runs app (runs 0001 takes them over).

State only: their tables and rows are untouched here; runs 0002 renames the tables.
"""

from django.db import migrations


class Migration(migrations.Migration):
    dependencies = [
        ("experiments", "0003_run_rail_length"),
        ("runs", "0001_initial"),
    ]

    operations = [
        migrations.SeparateDatabaseAndState(
            database_operations=[],
            state_operations=[
                migrations.DeleteModel(name="Sample"),
                migrations.DeleteModel(name="RunEvent"),
                migrations.DeleteModel(name="Run"),
            ],
        ),
    ]
