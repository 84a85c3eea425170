"""Calendar feed secrets kept as their SHA-256 only; the addresses already handed out keep
working (their secret's digest is what is looked up now)."""

import hashlib

from django.db import migrations, models


def tokens_to_digests(apps, schema_editor):
    CalendarFeed = apps.get_model("bookings", "CalendarFeed")
    for feed in CalendarFeed.objects.all().only("pk", "token"):
        digest = hashlib.sha256(feed.token.encode()).hexdigest()
        CalendarFeed.objects.filter(pk=feed.pk).update(token_digest=digest)


def digests_back(apps, schema_editor):
    # The secrets are gone: going back leaves each feed a value no address carries, so the
    # old addresses stop working and each user makes new ones.
    CalendarFeed = apps.get_model("bookings", "CalendarFeed")
    CalendarFeed.objects.update(token=models.F("token_digest"))


class Migration(migrations.Migration):
    dependencies = [
        ("bookings", "0011_agent_credential"),
    ]

    operations = [
        migrations.AddField(
            model_name="calendarfeed",
            name="token_digest",
            field=models.CharField(max_length=64, null=True),
        ),
        # Nullable before it goes, so that going back can add it again to a table with rows.
        migrations.AlterField(
            model_name="calendarfeed",
            name="token",
            field=models.CharField(max_length=64, null=True, unique=True),
        ),
        migrations.RunPython(tokens_to_digests, digests_back),
        migrations.RemoveField(model_name="calendarfeed", name="token"),
        migrations.AlterField(
            model_name="calendarfeed",
            name="token_digest",
            field=models.CharField(max_length=64, unique=True),
        ),
    ]
