"""The roof as the pages draw it: a robot's rail, its grid cells and the fixed nodes' places,
relayed from the robot's agent (``GET /api/v1/rail``, docs/agent-api.md).

The rail is configuration on the base station and changes only when the agent restarts with
another file, so the portal keeps the drawing a few minutes: every viewer of every run page
costs the agent one call in that time, not one each.
"""

from __future__ import annotations

import logging
from typing import Any, Final

from django.core.cache import cache

from basestation.client import AgentError
from bookings.models import Resource
from core.cache import database_namespace
from core.errors import InvalidInput
from portal.runs.agents import AgentNotConfigured, agent_client_for
from portal.runs.services.robot import AgentUnavailable

logger = logging.getLogger(__name__)

RAIL_CACHE_S: Final = 300


def rail_drawing(*, resource: Resource) -> dict[str, Any]:
    """The rail of ``resource`` drawn for a map (the agent's answer, see docs/agent-api.md).

    Raises :class:`InvalidInput` for a resource that is not a mobile node and
    :class:`AgentUnavailable` when its agent cannot be asked or does not answer.
    """
    if not resource.is_mobile:
        raise InvalidInput.on_field("resource", f"{resource.name} is not a mobile node.")
    key = f"rail-drawing:{database_namespace()}:{resource.pk}:{resource.agent_url}"
    hit = cache.get(key)
    if isinstance(hit, dict):
        return hit
    try:
        drawing = agent_client_for(resource).rail()
    except (AgentNotConfigured, AgentError) as exc:
        # Every signed-in user reads this: the agent's address and its answer go to the log
        # (for the admins), the user learns only that the rail is not to be had now.
        logger.warning("rail of %s unavailable: %s", resource.name, exc)
        raise AgentUnavailable(
            f"The base station of {resource.name} did not give its rail; try again later."
        ) from exc
    cache.set(key, drawing, RAIL_CACHE_S)
    return drawing
