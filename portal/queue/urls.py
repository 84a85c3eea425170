from django.urls import path

from portal.queue import apis

urlpatterns = [
    path("queue/", apis.QueueListApi.as_view(), name="api-queue"),
    path("queue/state/", apis.QueueStateApi.as_view(), name="api-queue-state"),
    path("queue/pause/", apis.QueuePauseApi.as_view(), name="api-queue-pause"),
    path("queue/resume/", apis.QueueResumeApi.as_view(), name="api-queue-resume"),
    path("queue/<int:pk>/", apis.QueueDetailApi.as_view(), name="api-queue-request"),
    path("queue/<int:pk>/reorder/", apis.QueueReorderApi.as_view(), name="api-queue-reorder"),
]
