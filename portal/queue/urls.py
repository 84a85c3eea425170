from django.urls import path

from portal.queue import apis

urlpatterns = [
    path("queue/", apis.QueueListApi.as_view(), name="api-queue"),
    path("queue/state/", apis.QueueStateApi.as_view(), name="api-queue-state"),
    path("queue/pause/", apis.QueuePauseApi.as_view(), name="api-queue-pause"),
    path("queue/resume/", apis.QueueResumeApi.as_view(), name="api-queue-resume"),
    path("queue/<int:pk>/", apis.QueueDetailApi.as_view(), name="api-queue-request"),
    path("queue/<int:pk>/reorder/", apis.QueueReorderApi.as_view(), name="api-queue-reorder"),
    path("campaigns/", apis.CampaignListApi.as_view(), name="api-campaigns"),
    path("campaigns/<int:pk>/", apis.CampaignDetailApi.as_view(), name="api-campaign"),
    path(
        "campaigns/<int:pk>/results/",
        apis.CampaignResultsApi.as_view(),
        name="api-campaign-results",
    ),
    path(
        "campaigns/<int:pk>/package.zip",
        apis.CampaignPackageApi.as_view(),
        name="api-campaign-package",
    ),
    path("campaigns/<int:pk>/pause/", apis.CampaignPauseApi.as_view(), name="api-campaign-pause"),
    path(
        "campaigns/<int:pk>/resume/", apis.CampaignResumeApi.as_view(), name="api-campaign-resume"
    ),
    path(
        "campaigns/<int:pk>/cancel/", apis.CampaignCancelApi.as_view(), name="api-campaign-cancel"
    ),
]
