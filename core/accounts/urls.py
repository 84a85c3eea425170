from django.urls import path

from core.accounts import apis

urlpatterns = [
    path("me/", apis.MeApi.as_view(), name="api-me"),
    path("auth/token/", apis.ApiTokenApi.as_view(), name="api-token"),
]
