"""The lease vocabulary of the testbed scheduler, served for the portal's mobile nodes.

Mounted at ``/scheduler/`` (``portal/urls.py``): a client configured with the base URL
``https://<portal>/scheduler`` speaks to it as to the broker. Paths with or without a trailing
slash, as omf_sfa accepts both.
"""

from django.urls import re_path

from bookings import inbound

urlpatterns = [
    re_path(r"^resources/nodes/?$", inbound.InboundNodesApi.as_view(), name="inbound-nodes"),
    re_path(r"^resources/leases/?$", inbound.InboundLeasesApi.as_view(), name="inbound-leases"),
]
