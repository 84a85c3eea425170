from django.urls import path

from portal.runs.apis import attach, measurements, rail, reservations, robot, runs, self_checks

urlpatterns = [
    path("runs/", runs.RunListApi.as_view(), name="api-runs"),
    path("runs/<int:pk>/", runs.RunDetailApi.as_view(), name="api-run"),
    path("runs/<int:pk>/samples/", runs.RunSamplesApi.as_view(), name="api-run-samples"),
    path("runs/<int:pk>/samples.csv", runs.RunSamplesCsvApi.as_view(), name="api-run-samples-csv"),
    path(
        "runs/<int:pk>/samples.json", runs.RunSamplesJsonApi.as_view(), name="api-run-samples-json"
    ),
    path(
        "runs/<int:pk>/samples.parquet",
        runs.RunSamplesParquetApi.as_view(),
        name="api-run-samples-parquet",
    ),
    path("runs/<int:pk>/analysis/", runs.RunAnalysisApi.as_view(), name="api-run-analysis"),
    path(
        "runs/<int:pk>/measurements/",
        measurements.MeasurementListApi.as_view(),
        name="api-run-measurements",
    ),
    path(
        "runs/<int:pk>/measurements/<slug:name>/",
        measurements.MeasurementApi.as_view(),
        name="api-run-measurement",
    ),
    path(
        "runs/<int:pk>/measurements/<slug:name>/points.parquet",
        runs.MeasurementParquetApi.as_view(),
        name="api-run-measurement-parquet",
    ),
    path("runs/<int:pk>/again/", reservations.RunAgainApi.as_view(), name="api-run-again"),
    path("runs/<int:pk>/package.zip", runs.RunPackageApi.as_view(), name="api-run-package"),
    path("reservations/", reservations.ReservationListApi.as_view(), name="api-reservations"),
    path(
        "reservations/check/",
        reservations.ReservationCheckApi.as_view(),
        name="api-reservations-check",
    ),
    path(
        "reservations/<int:pk>/",
        reservations.ReservationDetailApi.as_view(),
        name="api-reservation",
    ),
    path(
        "reservations/<int:pk>/attach/",
        attach.ReservationAttachApi.as_view(),
        name="api-reservation-attach",
    ),
    path(
        "reservations/<int:pk>/decision/",
        reservations.ReservationDecisionApi.as_view(),
        name="api-reservation-decision",
    ),
    # The check's first name, for one release (deprecated in the schema).
    path("quota/check/", reservations.QuotaCheckApi.as_view(), name="api-quota-check"),
    path("resources/<slug:name>/rail/", rail.RailApi.as_view(), name="api-rail"),
    path("resources/<slug:name>/robot/", robot.RobotStatusApi.as_view(), name="api-robot"),
    path(
        "resources/<slug:name>/robot/control/",
        robot.RobotDriveApi.as_view(),
        name="api-robot-drive",
    ),
    path("resources/<slug:name>/robot/stop/", robot.RobotStopApi.as_view(), name="api-robot-stop"),
    path(
        "resources/<slug:name>/robot/release/",
        robot.RobotReleaseApi.as_view(),
        name="api-robot-release",
    ),
    path(
        "resources/<slug:name>/self-checks/",
        self_checks.SelfCheckListApi.as_view(),
        name="api-self-checks",
    ),
    path(
        "resources/<slug:name>/self-checks/schedule/",
        self_checks.SelfCheckScheduleApi.as_view(),
        name="api-self-check-schedule",
    ),
    path(
        "self-checks/<int:pk>/baseline/",
        self_checks.SelfCheckBaselineApi.as_view(),
        name="api-self-check-baseline",
    ),
    path(
        "resources/<slug:name>/robot/logs/<str:day>/",
        robot.RobotLogApi.as_view(),
        name="api-robot-log",
    ),
]
