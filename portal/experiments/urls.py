from django.urls import path

from portal.experiments import apis

urlpatterns = [
    path("experiments/", apis.ExperimentListApi.as_view(), name="api-experiments"),
    path("experiments/<int:pk>/", apis.ExperimentDetailApi.as_view(), name="api-experiment"),
    path("runs/", apis.RunListApi.as_view(), name="api-runs"),
    path("runs/<int:pk>/", apis.RunDetailApi.as_view(), name="api-run"),
    path("runs/<int:pk>/samples/", apis.RunSamplesApi.as_view(), name="api-run-samples"),
    path("runs/<int:pk>/samples.csv", apis.RunSamplesCsvApi.as_view(), name="api-run-samples-csv"),
    path(
        "runs/<int:pk>/samples.json", apis.RunSamplesJsonApi.as_view(), name="api-run-samples-json"
    ),
    path("runs/<int:pk>/analysis/", apis.RunAnalysisApi.as_view(), name="api-run-analysis"),
]
