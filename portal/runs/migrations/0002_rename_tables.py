"""The moved tables take this app's names; permissions and admin history follow them."""

from django.db import migrations

MODELS = ("run", "runevent", "sample")


def move_content_types(apps, schema_editor):
    content_type = apps.get_model("contenttypes", "ContentType")
    db = schema_editor.connection.alias
    for model in MODELS:
        old = content_type.objects.using(db).filter(app_label="experiments", model=model)
        if content_type.objects.using(db).filter(app_label="runs", model=model).exists():
            continue  # created already (a database migrated by hand): keep the new one
        old.update(app_label="runs")


def move_content_types_back(apps, schema_editor):
    content_type = apps.get_model("contenttypes", "ContentType")
    db = schema_editor.connection.alias
    content_type.objects.using(db).filter(app_label="runs", model__in=MODELS).update(
        app_label="experiments"
    )


class Migration(migrations.Migration):
    dependencies = [
        ("contenttypes", "0002_remove_content_type_name"),
        ("experiments", "0004_runs_moved_to_runs_app"),
        ("runs", "0001_initial"),
    ]

    operations = [
        migrations.AlterModelTable(name="run", table=None),
        migrations.AlterModelTable(name="runevent", table=None),
        migrations.AlterModelTable(name="sample", table=None),
        migrations.RunPython(move_content_types, move_content_types_back),
    ]
