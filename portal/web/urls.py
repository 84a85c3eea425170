from django.urls import path

from portal.web import (
    attach,
    calendars,
    console,
    dry_runs,
    live,
    measurements,
    my_runs,
    roof,
    timeline,
    views,
    webhooks,
)

urlpatterns = [
    path("", views.home, name="home"),
    path("experiments/new/", views.experiment_edit, name="experiment-new"),
    path("experiments/<int:pk>/", views.experiment_edit, name="experiment-edit"),
    path("experiments/<int:pk>/dry-run/", dry_runs.dry_run_start, name="dry-run-start"),
    path("dry-runs/<int:pk>/", dry_runs.dry_run_page, name="dry-run"),
    path("dry-runs/<int:pk>/data.json", dry_runs.dry_run_data, name="dry-run-data"),
    path("book/", views.book, name="book"),
    path("reservations/<int:pk>/cancel/", views.reservation_cancel_view, name="reservation-cancel"),
    path(
        "reservations/<int:pk>/attach/", attach.reservation_attach_view, name="reservation-attach"
    ),
    path("runs/", my_runs.my_runs, name="my-runs"),
    path("runs/package.zip", my_runs.runs_package, name="runs-package"),
    path("runs/compare/", my_runs.runs_compare, name="runs-compare"),
    path("runs/<int:pk>/", views.run_page, name="run"),
    path("runs/<int:pk>/data.json", views.run_data, name="run-data"),
    path("runs/<int:pk>/samples.csv", views.run_csv, name="run-csv"),
    path("runs/<int:pk>/samples.json", views.run_json, name="run-json"),
    path("runs/<int:pk>/package.zip", views.run_package, name="run-package"),
    path("runs/<int:pk>/again/", views.run_again, name="run-again"),
    path(
        "runs/<int:pk>/measurements/",
        measurements.measurement_add_view,
        name="run-measurement-add",
    ),
    path(
        "runs/<int:pk>/measurements/series/",
        measurements.measurement_series_part,
        name="run-measurement-series",
    ),
    path(
        "runs/<int:pk>/measurements/<slug:name>/offset/",
        measurements.measurement_offset_view,
        name="run-measurement-offset",
    ),
    path(
        "runs/<int:pk>/measurements/<slug:name>/delete/",
        measurements.measurement_delete_view,
        name="run-measurement-delete",
    ),
    path("calendar/", calendars.calendar_page, name="calendar"),
    path("calendar/timeline/", timeline.timeline_page, name="timeline"),
    path("calendar/events.json", calendars.calendar_events, name="calendar-events"),
    path("calendar/feeds/", calendars.calendar_feeds, name="calendar-feeds"),
    path("calendar/feed/<str:token>.ics", calendars.ical_personal, name="ical-personal"),
    path(
        "calendar/feed/<str:token>/<slug:name>.ics", calendars.ical_resource, name="ical-resource"
    ),
    path("account/tokens/", views.api_tokens_page, name="api-tokens"),
    path("account/webhooks/", webhooks.webhooks_page, name="webhooks"),
    path("account/webhooks/<int:pk>/", webhooks.webhook_page, name="webhook"),
    path("account/webhooks/<int:pk>/test/", webhooks.webhook_test_view, name="webhook-test"),
    path("account/webhooks/<int:pk>/resume/", webhooks.webhook_resume_view, name="webhook-resume"),
    path("account/webhooks/<int:pk>/delete/", webhooks.webhook_delete_view, name="webhook-delete"),
    path("approvals/", views.approvals, name="approvals"),
    path("robot/<slug:name>/", views.robot_console, name="robot"),
    path("robot/<slug:name>/log.csv", console.robot_log_csv, name="robot-log-csv"),
    path("rails/<slug:name>.json", roof.rail_json, name="rail-json"),
    path("usage/", views.usage_report, name="usage"),
    path("scheduler-link/", views.scheduler_link, name="scheduler-link"),
    # Server-Sent Events (portal/web/live.py): the pages' live updates.
    path("live/runs/<int:pk>/", live.run_stream, name="live-run"),
    path("live/robots/<slug:name>/", live.robot_stream, name="live-robot"),
    path("live/calendar/", live.calendar_stream, name="live-calendar"),
]
