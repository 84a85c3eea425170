"""The lease vocabulary of the testbed scheduler, served for the portal's mobile nodes.

Mounted at ``/scheduler/`` (``portal/urls.py``): a client configured with the base URL
``https://<portal>/scheduler`` speaks to it as to the broker. Paths with or without a trailing
slash, as omf_sfa accepts both. The nodes are the bookings layer's (``bookings/inbound.py``);
the leases are served here, in the runs layer, because a lease may hold a run.
"""

from django.urls import re_path

from bookings.inbound import InboundNodesApi
from portal.runs.apis.leases import InboundLeasesApi

urlpatterns = [
    re_path(r"^resources/nodes/?$", InboundNodesApi.as_view(), name="inbound-nodes"),
    re_path(r"^resources/leases/?$", InboundLeasesApi.as_view(), name="inbound-leases"),
]
