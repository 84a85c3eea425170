from django.urls import path

from core.events import apis

urlpatterns = [
    path("events/", apis.EventListApi.as_view(), name="api-events"),
]
