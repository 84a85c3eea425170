from django.db import migrations, models


class Migration(migrations.Migration):
    """Types that happen once to a subject (a reservation's reminder, a run's data ready) are
    held once by the database too."""

    dependencies = [("events", "0001_initial")]

    operations = [
        migrations.AddConstraint(
            model_name="event",
            constraint=models.UniqueConstraint(
                condition=models.Q(("type__in", ["reservation.starting_soon", "run.data_ready"])),
                fields=("subject", "type"),
                name="event_once_per_subject",
            ),
        ),
    ]
