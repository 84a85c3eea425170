from django.contrib import admin
from django.urls import include, path, re_path
from drf_spectacular.views import SpectacularAPIView, SpectacularSwaggerSplitView

from core.api import api_not_found
from portal.runs.metrics import metrics_view
from portal.web.views import healthz

urlpatterns = [
    path("healthz", healthz, name="healthz"),
    path("metrics", metrics_view, name="metrics"),
    path("accounts/", include("allauth.urls")),
    path("admin/", admin.site.urls),
    path("api/schema/", SpectacularAPIView.as_view(), name="schema"),
    path(
        "api/docs/",
        SpectacularSwaggerSplitView.as_view(url_name="schema", template_name="web/api_docs.html"),
        name="swagger-ui",
    ),
    path("api/v1/", include("portal.experiments.urls")),
    path("api/v1/", include("portal.runs.urls")),
    path("api/v1/", include("portal.queue.urls")),
    path("api/v1/", include("bookings.urls")),
    path("api/v1/", include("core.audit.urls")),
    path("api/v1/", include("core.events.urls")),
    path("api/v1/", include("core.webhooks.urls")),
    path("api/v1/", include("core.accounts.urls")),
    # Last of the API: any other path under /api/ answers a JSON 404, not a page.
    re_path(r"^api/(?P<path>.*)$", api_not_found),
    # The testbed scheduler's own lease vocabulary, for the robot (bookings/inbound.py,
    # portal/runs/apis/leases.py).
    path("scheduler/", include("portal.runs.urls_inbound")),
    path("", include("portal.web.urls")),
]
