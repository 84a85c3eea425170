"""``manage.py agent_token issue ROBOT``: a new token for one robot's base-station agent.

Prints the two halves of it: the token, which the portal presents (an entry of
``AGENT_TOKENS``, named after the robot), and its SHA-256 digest, which the agent keeps
(``AGENT_TOKEN_SHA256``) instead of the token, so a base station never holds a usable token.
Nothing is stored here: the token is shown once.

Rotation without a refused call (docs/operations.md): give the agent the new digest beside
the old one and restart it; give the portal the new token and restart it; then drop the old
digest from the agent. Revoking is dropping a digest.
"""

from __future__ import annotations

import hashlib
import secrets
from typing import Any

from django.core.management.base import BaseCommand, CommandError, CommandParser

from bookings.choices import ResourceKind
from bookings.models import Resource

TOKEN_BYTES = 32
# The name under which AGENT_TOKEN (shared by every agent without a token of its own) goes.
SHARED_TOKEN_NAME = "default"  # noqa: S105 (a name, not a secret)


class Command(BaseCommand):
    help = "Issue a new bearer token for a robot's agent: the portal's half and the agent's."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("action", choices=["issue"])
        parser.add_argument("robot", help="the robot's resource name, e.g. mobile-1")

    def handle(self, *args: Any, **options: Any) -> None:
        name = options["robot"]
        resource = Resource.objects.filter(name=name, kind=ResourceKind.MOBILE).first()
        if resource is None:
            raise CommandError(f"no robot named {name!r}")
        token = secrets.token_urlsafe(TOKEN_BYTES)
        digest = hashlib.sha256(token.encode()).hexdigest()
        token_name = resource.agent_token_name or SHARED_TOKEN_NAME
        self.stdout.write(
            f"A new token for {name}'s agent (shown once, stored nowhere):\n\n"
            f"  portal, in AGENT_TOKENS (or its _FILE):  {token_name}={token}\n"
            f"  agent, in AGENT_TOKEN_SHA256 (beside the old digest while rotating):\n"
            f"      {digest}\n"
        )
        if token_name == SHARED_TOKEN_NAME:
            self.stdout.write(
                f"\n{name} uses AGENT_TOKEN (the name 'default'): to give it a token of its "
                f"own, set its agent token name to {name} in the admin and use that name above.\n"
            )
