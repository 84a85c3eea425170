from django.urls import path

from bookings import apis

urlpatterns = [
    path("resources/", apis.ResourceListApi.as_view(), name="api-resources"),
    path("reservations/", apis.ReservationListApi.as_view(), name="api-reservations"),
    path("reservations/<int:pk>/", apis.ReservationDetailApi.as_view(), name="api-reservation"),
]
