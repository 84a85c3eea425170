"""Create the demo users and the testbed's resources, once.

Passwords are random and printed only when the users are created; run ``changepassword``
to set new ones later.

A start without the second robot after one with it (``make run`` after ``make run
ROBOTS=2``) finds ``mobile-2`` with no agent running and no token for it: it is taken out of
booking ("agent not configured"), and the next start with it puts it back.
"""

from __future__ import annotations

import secrets
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
from core.accounts.models import User
from core.fleet import SECOND_ROBOT


class Command(BaseCommand):
    help = "Create an admin, an experimenter, the mobile node and the 24 fixed nodes (idempotent)."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument(
            "--second-robot",
            metavar="AGENT_URL",
            help="also create the second simulated robot (mobile-2), whose agent is here; "
            "its token is AGENT_TOKENS' mobile-2",
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
