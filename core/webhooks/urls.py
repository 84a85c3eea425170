from django.urls import path

from core.webhooks import apis

urlpatterns = [
    path("webhooks/", apis.WebhookListApi.as_view(), name="api-webhooks"),
    path("webhooks/<int:pk>/", apis.WebhookDetailApi.as_view(), name="api-webhook"),
    path("webhooks/<int:pk>/resume/", apis.WebhookResumeApi.as_view(), name="api-webhook-resume"),
    path("webhooks/<int:pk>/test/", apis.WebhookTestApi.as_view(), name="api-webhook-test"),
    path(
        "webhooks/<int:pk>/deliveries/",
        apis.WebhookDeliveryListApi.as_view(),
        name="api-webhook-deliveries",
    ),
]
