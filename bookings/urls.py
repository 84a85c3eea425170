from django.urls import path

from bookings import apis

urlpatterns = [
    path("resources/", apis.ResourceListApi.as_view(), name="api-resources"),
    path(
        "resources/<slug:name>/availability/",
        apis.AvailabilityApi.as_view(),
        name="api-resource-availability",
    ),
    path("resources/<slug:name>/service/", apis.ResourceServiceApi.as_view(), name="api-service"),
    path("resources/<slug:name>/robot/", apis.RobotStatusApi.as_view(), name="api-robot"),
    path(
        "resources/<slug:name>/robot/control/", apis.RobotDriveApi.as_view(), name="api-robot-drive"
    ),
    path("resources/<slug:name>/robot/stop/", apis.RobotStopApi.as_view(), name="api-robot-stop"),
    path(
        "resources/<slug:name>/robot/release/",
        apis.RobotReleaseApi.as_view(),
        name="api-robot-release",
    ),
    path(
        "resources/<slug:name>/robot/logs/<str:day>/",
        apis.RobotLogApi.as_view(),
        name="api-robot-log",
    ),
    path("reservations/", apis.ReservationListApi.as_view(), name="api-reservations"),
    path("reservations/busy/", apis.BusyApi.as_view(), name="api-reservations-busy"),
    path("reservations/<int:pk>/", apis.ReservationDetailApi.as_view(), name="api-reservation"),
    path(
        "reservations/<int:pk>/decision/",
        apis.ReservationDecisionApi.as_view(),
        name="api-reservation-decision",
    ),
    path("quota/", apis.QuotaApi.as_view(), name="api-quota"),
    path("quota/check/", apis.QuotaCheckApi.as_view(), name="api-quota-check"),
    path("quota-policies/", apis.QuotaPolicyListApi.as_view(), name="api-quota-policies"),
    path("quota-policies/<int:pk>/", apis.QuotaPolicyDetailApi.as_view(), name="api-quota-policy"),
    path("blackouts/", apis.BlackoutListApi.as_view(), name="api-blackouts"),
]
