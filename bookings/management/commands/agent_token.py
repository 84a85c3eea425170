"""``manage.py agent_token ACTION ROBOT``: each robot's agent token, kept by the portal.

The portal stores the token (encrypted, ``bookings/agent_tokens.py``) and presents it; the
robot's agent keeps only its SHA-256 digest (``AGENT_TOKEN_SHA256``). The token itself is
never printed: what this command prints is what goes on the base station.

- ``issue ROBOT``: a first token for the robot (``--from-environment``: store the token the
  environment gives it today, so its agent needs no change).
- ``rotate ROBOT``: a next token beside the current one, which stays in use; give the agent
  both digests and restart it, then ``rotate ROBOT --finish``: the portal presents the next
  token from its next call on; then drop the old digest from the agent.
- ``revoke ROBOT``: forget the robot's tokens (its agent should drop their digests).
- ``show ROBOT``: the digests its agent must accept now.
"""

from __future__ import annotations

from typing import Any

from django.core.management.base import BaseCommand, CommandError, CommandParser

from bookings.agent_tokens import (
    AgentTokenError,
    AgentTokens,
    AgentTokenUnreadable,
    agent_token_from_environment,
    agent_token_issue,
    agent_token_revoke,
    agent_token_rotate,
    agent_token_rotation_finish,
    agent_tokens_show,
)


class Command(BaseCommand):
    help = "Issue, rotate, revoke or show a robot's agent token (the agent gets only digests)."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("action", choices=["issue", "rotate", "revoke", "show"])
        parser.add_argument("robot", help="the robot's resource name, e.g. mobile-1")
        parser.add_argument(
            "--finish",
            action="store_true",
            help="rotate: the agent accepts both digests now; present the next token",
        )
        parser.add_argument(
            "--from-environment",
            action="store_true",
            help="issue: store the token AGENT_TOKEN/AGENT_TOKENS gives the robot today",
        )

    def handle(self, *args: Any, **options: Any) -> None:
        action, robot = options["action"], options["robot"]
        if options["finish"] and action != "rotate":
            raise CommandError("--finish goes with rotate")
        if options["from_environment"] and action != "issue":
            raise CommandError("--from-environment goes with issue")
        try:
            if action == "issue":
                token = (
                    agent_token_from_environment(robot=robot)
                    if options["from_environment"]
                    else None
                )
                tokens = agent_token_issue(robot=robot, token=token)
                self._say(
                    f"{robot} has its own agent token now; the portal presents it from its "
                    "next call. On the base station:",
                    tokens,
                )
            elif action == "rotate" and not options["finish"]:
                tokens = agent_token_rotate(robot=robot)
                self._say(
                    f"A next token for {robot} is stored; the portal still presents the "
                    "current one. On the base station, accept both and restart the agent:",
                    tokens,
                )
                self.stdout.write(f"\nThen: manage.py agent_token rotate {robot} --finish\n")
            elif action == "rotate":
                tokens = agent_token_rotation_finish(robot=robot)
                self._say(
                    f"The portal presents {robot}'s new token from its next call on. On the "
                    "base station, drop the old digest and restart the agent:",
                    tokens,
                )
            elif action == "revoke":
                revoked = agent_token_revoke(robot=robot)
                self.stdout.write(
                    f"{robot}'s stored agent token is gone: the portal falls back to the "
                    "environment's token for it (AGENT_TOKEN/AGENT_TOKENS), if any.\n"
                )
                if revoked is None:
                    self.stdout.write("(it could not be decrypted: its digest is unknown)\n")
                else:
                    self.stdout.write(
                        "On the base station, remove these digests from AGENT_TOKEN_SHA256:\n"
                        + "".join(f"    {digest}\n" for digest in revoked.agent_digests)
                    )
            else:
                shown = agent_tokens_show(robot=robot)
                if shown is None:
                    self.stdout.write(
                        f"{robot} has no stored agent token (the environment's applies)\n"
                    )
                else:
                    self._say(f"{robot}'s agent must accept:", shown)
        except (AgentTokenError, AgentTokenUnreadable) as exc:
            raise CommandError(str(exc)) from exc

    def _say(self, headline: str, tokens: AgentTokens) -> None:
        digests = ",".join(tokens.agent_digests)
        self.stdout.write(f"{headline}\n\n    AGENT_TOKEN_SHA256={digests}\n")
