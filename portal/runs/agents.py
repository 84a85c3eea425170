"""The only way the portal reaches a base-station agent: its REST client."""

from __future__ import annotations

from django.conf import settings
from django.core.exceptions import ImproperlyConfigured

from basestation.client import AgentClient
from bookings.agent_tokens import AgentTokenUnreadable, agent_token_stored
from bookings.models import Resource
from core.logs import current_request_id

# The name of AGENT_TOKEN among AGENT_TOKENS (a name, not a secret).
DEFAULT_TOKEN_NAME = "default"  # noqa: S105


class AgentNotConfigured(ImproperlyConfigured):
    """The portal has no way to reach this robot's agent (no URL, or no token for it)."""

    def __init__(self, resource: Resource, why: str) -> None:
        super().__init__(f"resource {resource.name} {why}")
        self.why = why


def agent_token_for(resource: Resource) -> str:
    """The robot's own stored token (``manage.py agent_token``), else the environment's
    token named by ``Resource.agent_token_name``."""
    try:
        token = agent_token_stored(resource)
    except AgentTokenUnreadable as exc:
        raise AgentNotConfigured(resource, str(exc)) from exc
    if token:
        return token
    named = resource.agent_token_name or DEFAULT_TOKEN_NAME
    token = settings.AGENT_TOKENS.get(named)
    if not token:
        setting = "AGENT_TOKEN" if named == DEFAULT_TOKEN_NAME else "AGENT_TOKENS"
        raise AgentNotConfigured(
            resource,
            f"names agent token {named!r}, which is not configured ({setting})",
        )
    return token


def agent_client_for(resource: Resource) -> AgentClient:
    if not resource.agent_url:
        raise AgentNotConfigured(resource, "has no agent URL")
    return AgentClient(
        resource.agent_url,
        agent_token_for(resource),
        timeout_s=settings.AGENT_TIMEOUT_S,
        request_id=current_request_id,
    )
