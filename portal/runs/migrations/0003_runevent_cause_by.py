"""Each change of a run's state says what caused it (booking, dispatch, an admin) and who."""

import django.db.models.deletion
from django.conf import settings
from django.db import migrations, models


class Migration(migrations.Migration):
    dependencies = [
        ("runs", "0002_rename_tables"),
        migrations.swappable_dependency(settings.AUTH_USER_MODEL),
    ]

    operations = [
        migrations.AddField(
            model_name="runevent",
            name="cause",
            field=models.CharField(
                blank=True,
                choices=[
                    ("booking", "booking"),
                    ("dispatch", "dispatch"),
                    ("admin", "admin action"),
                ],
                max_length=16,
            ),
        ),
        migrations.AddField(
            model_name="runevent",
            name="by",
            field=models.ForeignKey(
                blank=True,
                null=True,
                on_delete=django.db.models.deletion.SET_NULL,
                related_name="+",
                to=settings.AUTH_USER_MODEL,
            ),
        ),
    ]
