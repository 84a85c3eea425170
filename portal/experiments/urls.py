from django.urls import path

from portal.experiments import apis

urlpatterns = [
    path("experiments/", apis.ExperimentListApi.as_view(), name="api-experiments"),
    path("experiments/<int:pk>/", apis.ExperimentDetailApi.as_view(), name="api-experiment"),
]
