"""Runs, their events and samples move here from the experiments app, with their data.

The tables stay where they are in this step (only Django's idea of which app owns the models
changes); 0002 renames them to this app's names and moves their content types along.
"""

import django.db.models.deletion
from django.db import migrations, models


class Migration(migrations.Migration):
    initial = True

    dependencies = [
        ("bookings", "0004_agent_url_bare_host_names"),
        ("experiments", "0003_run_rail_length"),
    ]

    operations = [
        migrations.SeparateDatabaseAndState(
            database_operations=[],
            state_operations=[
                migrations.CreateModel(
                    name="Run",
                    fields=[
                        (
                            "id",
                            models.BigAutoField(
                                auto_created=True,
                                primary_key=True,
                                serialize=False,
                                verbose_name="ID",
                            ),
                        ),
                        ("title", models.CharField(max_length=200)),
                        ("segments", models.JSONField()),
                        ("start_at", models.DateTimeField(db_index=True)),
                        ("end_at", models.DateTimeField()),
                        (
                            "state",
                            models.CharField(
                                choices=[
                                    ("scheduled", "scheduled"),
                                    ("staged", "staged on the base station"),
                                    ("running", "running"),
                                    ("collecting", "collecting data"),
                                    ("completed", "completed"),
                                    ("cancelled", "cancelled"),
                                    ("failed", "failed"),
                                    ("interrupted", "interrupted (partial data kept)"),
                                ],
                                db_index=True,
                                default="scheduled",
                                max_length=16,
                            ),
                        ),
                        ("reason", models.TextField(blank=True)),
                        ("last_seq", models.PositiveIntegerField(default=0)),
                        ("agent_sample_count", models.PositiveIntegerField(blank=True, null=True)),
                        ("rail_length_m", models.FloatField(blank=True, null=True)),
                        ("created_at", models.DateTimeField(auto_now_add=True)),
                        ("updated_at", models.DateTimeField(auto_now=True)),
                        (
                            "experiment",
                            models.ForeignKey(
                                on_delete=django.db.models.deletion.PROTECT,
                                related_name="runs",
                                to="experiments.experiment",
                            ),
                        ),
                        (
                            "reservation",
                            models.OneToOneField(
                                on_delete=django.db.models.deletion.CASCADE,
                                related_name="run",
                                to="bookings.reservation",
                            ),
                        ),
                        (
                            "resource",
                            models.ForeignKey(
                                on_delete=django.db.models.deletion.PROTECT,
                                related_name="runs",
                                to="bookings.resource",
                            ),
                        ),
                    ],
                    options={
                        "ordering": ["-start_at"],
                        "db_table": "experiments_run",
                    },
                ),
                migrations.CreateModel(
                    name="RunEvent",
                    fields=[
                        (
                            "id",
                            models.BigAutoField(
                                auto_created=True,
                                primary_key=True,
                                serialize=False,
                                verbose_name="ID",
                            ),
                        ),
                        (
                            "from_state",
                            models.CharField(
                                blank=True,
                                choices=[
                                    ("scheduled", "scheduled"),
                                    ("staged", "staged on the base station"),
                                    ("running", "running"),
                                    ("collecting", "collecting data"),
                                    ("completed", "completed"),
                                    ("cancelled", "cancelled"),
                                    ("failed", "failed"),
                                    ("interrupted", "interrupted (partial data kept)"),
                                ],
                                max_length=16,
                            ),
                        ),
                        (
                            "to_state",
                            models.CharField(
                                choices=[
                                    ("scheduled", "scheduled"),
                                    ("staged", "staged on the base station"),
                                    ("running", "running"),
                                    ("collecting", "collecting data"),
                                    ("completed", "completed"),
                                    ("cancelled", "cancelled"),
                                    ("failed", "failed"),
                                    ("interrupted", "interrupted (partial data kept)"),
                                ],
                                max_length=16,
                            ),
                        ),
                        ("at", models.DateTimeField(auto_now_add=True)),
                        ("reason", models.TextField(blank=True)),
                        (
                            "run",
                            models.ForeignKey(
                                on_delete=django.db.models.deletion.CASCADE,
                                related_name="events",
                                to="runs.run",
                            ),
                        ),
                    ],
                    options={
                        "ordering": ["at", "pk"],
                        "db_table": "experiments_runevent",
                    },
                ),
                migrations.CreateModel(
                    name="Sample",
                    fields=[
                        (
                            "id",
                            models.BigAutoField(
                                auto_created=True,
                                primary_key=True,
                                serialize=False,
                                verbose_name="ID",
                            ),
                        ),
                        ("seq", models.PositiveIntegerField()),
                        ("t", models.DateTimeField()),
                        ("segment", models.SmallIntegerField(null=True)),
                        ("commanded_velocity_mps", models.FloatField()),
                        ("velocity_mps", models.FloatField()),
                        (
                            "direction",
                            models.CharField(
                                choices=[("cw", "clockwise"), ("ccw", "counter-clockwise")],
                                max_length=3,
                            ),
                        ),
                        ("battery_v", models.FloatField()),
                        ("track_m", models.FloatField()),
                        ("fix_quality", models.SmallIntegerField(null=True)),
                        ("lat_deg", models.FloatField(null=True)),
                        ("lon_deg", models.FloatField(null=True)),
                        ("grid_id", models.CharField(max_length=8, null=True)),
                        ("lap", models.IntegerField(null=True)),
                        (
                            "run",
                            models.ForeignKey(
                                on_delete=django.db.models.deletion.CASCADE,
                                related_name="samples",
                                to="runs.run",
                            ),
                        ),
                    ],
                    options={
                        "ordering": ["run", "seq"],
                        "db_table": "experiments_sample",
                    },
                ),
                migrations.AddConstraint(
                    model_name="run",
                    constraint=models.CheckConstraint(
                        condition=models.Q(("end_at__gt", models.F("start_at"))),
                        name="run_end_after_start",
                    ),
                ),
                migrations.AddConstraint(
                    model_name="run",
                    constraint=models.CheckConstraint(
                        condition=models.Q(
                            ("rail_length_m__isnull", True),
                            ("rail_length_m__gt", 0),
                            _connector="OR",
                        ),
                        name="run_rail_length_positive",
                    ),
                ),
                migrations.AddConstraint(
                    model_name="sample",
                    constraint=models.UniqueConstraint(
                        fields=("run", "seq"), name="sample_run_seq_unique"
                    ),
                ),
            ],
        ),
    ]
