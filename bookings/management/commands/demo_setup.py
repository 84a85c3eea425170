"""Create the demo users and the testbed's resources, once.

Passwords are random and printed only when the users are created; run ``changepassword``
to set new ones later.

``--rssi-token-file PATH`` writes a new API token of the demo experimenter there (the older
one of that name revoked): the demo's synthetic signal strength (``python -m
basestation.sim.rssi --watch``) pushes each of the experimenter's runs its series with it, as
any script of theirs would, through the API.

A start without the second robot after one with it (``make run`` after ``make run
ROBOTS=2``) finds ``mobile-2`` with no agent running and no token for it: it is taken out of
booking ("agent not configured"), and the next start with it puts it back.
"""

from __future__ import annotations

import secrets
from pathlib import Path
from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandParser
from django.db import transaction

from bookings.models import Resource
from bookings.services import (
    AGENT_NOT_CONFIGURED,
    TestbedSpec,
    fixed_node_names_from_scheduler,
    resource_hold,
    resource_hold_lift,
    testbed_resources_ensure,
)
from core.accounts.models import ApiToken, User
from core.accounts.services import api_token_create, api_token_revoke
from core.fleet import SECOND_ROBOT

RSSI_TOKEN_NAME = "demo: simulated signal strength"  # noqa: S105 (a token's name)


class Command(BaseCommand):
    help = "Create an admin, an experimenter, the mobile node and the 24 fixed nodes (idempotent)."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument(
            "--second-robot",
            metavar="AGENT_URL",
            help="also create the second simulated robot (mobile-2), whose agent is here; "
            "its token is AGENT_TOKENS' mobile-2",
        )
        parser.add_argument(
            "--rssi-token-file",
            metavar="PATH",
            help="write a new API token of the experimenter here, for the demo's synthetic "
            "signal strength (python -m basestation.sim.rssi --watch)",
        )

    def handle(self, *args: Any, **options: Any) -> None:
        with transaction.atomic():
            # The demo's resources are the real testbed's, on the local agent.
            # With a scheduler, the fixed nodes are the ones it leases.
            fixed_nodes = fixed_node_names_from_scheduler()
            testbed_resources_ensure(
                TestbedSpec(agent_url=settings.AGENT_URL, fixed_node_names=fixed_nodes)
            )
            if options["second_robot"]:
                testbed_resources_ensure(
                    TestbedSpec(
                        agent_url=options["second_robot"],
                        mobile_name=SECOND_ROBOT,
                        agent_token_name=SECOND_ROBOT,
                        mobile_description="Second simulated robot, on a second rail",
                        fixed_node_names=fixed_nodes,
                    )
                )
            self._second_robot_in_or_out(started=bool(options["second_robot"]))
            created = []
            for username, staff in (("admin", True), ("experimenter", False)):
                if User.objects.filter(username=username).exists():
                    continue
                password = secrets.token_urlsafe(12)
                User.objects.create_user(
                    username=username,
                    email=f"{username}@example.org",
                    password=password,
                    is_staff=staff,
                    is_superuser=staff,
                    # Made by the operator who runs this command: the demo admin may enrol
                    # its first factor (staff powers need it).
                    mfa_enrolment_allowed=staff,
                )
                created.append((username, password))
        for username, password in created:
            self.stdout.write(f"demo user created: {username} / password: {password}")
        if not created:
            self.stdout.write("demo users already exist (passwords were printed when created)")
        if options["rssi_token_file"]:
            self._rssi_token(Path(options["rssi_token_file"]))

    def _rssi_token(self, path: Path) -> None:
        """A fresh token of the experimenter for the demo's signal strength, only in ``path``
        (readable by its owner only); the previous start's is revoked."""
        experimenter = User.objects.get(username="experimenter")
        for old in ApiToken.objects.filter(user=experimenter, name=RSSI_TOKEN_NAME):
            api_token_revoke(user=experimenter, digest=old.digest)
        _, token = api_token_create(user=experimenter, name=RSSI_TOKEN_NAME)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.touch(mode=0o600)
        path.chmod(0o600)
        path.write_text(token + "\n")
        self.stdout.write(f"the demo's signal strength pushes with a token in {path}")

    def _second_robot_in_or_out(self, *, started: bool) -> None:
        """The second robot is bookable exactly when this start runs its agent."""
        robot = Resource.objects.filter(name=SECOND_ROBOT).first()
        if robot is None:
            return
        if started:
            if resource_hold_lift(
                resource_id=robot.pk,
                reason_prefix=AGENT_NOT_CONFIGURED,
                why="started again with its agent (ROBOTS=2)",
            ):
                self.stdout.write(f"{SECOND_ROBOT} back in booking: its agent runs again")
        elif resource_hold(
            resource_id=robot.pk,
            reason=f"{AGENT_NOT_CONFIGURED}: started without it (ROBOTS=2 runs its agent)",
        ):
            self.stdout.write(f"{SECOND_ROBOT} out of booking: started without its agent")
