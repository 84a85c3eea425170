"""The only way the portal reaches a base-station agent: its REST client."""

from __future__ import annotations

from django.conf import settings
from django.core.exceptions import ImproperlyConfigured

from basestation.client import AgentClient
from bookings.models import Resource


def agent_client_for(resource: Resource) -> AgentClient:
    if not resource.agent_url:
        raise ImproperlyConfigured(f"resource {resource.name} has no agent URL")
    token = settings.AGENT_TOKENS.get(resource.agent_token_name or "default")
    if not token:
        raise ImproperlyConfigured(
            f"resource {resource.name} names agent token {resource.agent_token_name!r}, "
            "which is not configured (AGENT_TOKEN)"
        )
    return AgentClient(resource.agent_url, token, timeout_s=settings.AGENT_TIMEOUT_S)
