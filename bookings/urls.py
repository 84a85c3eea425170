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
    path("reservations/busy/", apis.BusyApi.as_view(), name="api-reservations-busy"),
    path("quota/", apis.QuotaApi.as_view(), name="api-quota"),
    path("quota-policies/", apis.QuotaPolicyListApi.as_view(), name="api-quota-policies"),
    path("quota-policies/<int:pk>/", apis.QuotaPolicyDetailApi.as_view(), name="api-quota-policy"),
    path("blackouts/", apis.BlackoutListApi.as_view(), name="api-blackouts"),
]
