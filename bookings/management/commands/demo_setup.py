"""Create the demo users and the testbed's resources, once.

Passwords are random and printed only when the users are created; run ``changepassword``
to set new ones later.
"""

from __future__ import annotations

import secrets
from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandParser
from django.db import transaction

from bookings.services import (
    TestbedSpec,
    fixed_node_names_from_scheduler,
    testbed_resources_ensure,
)
from portal.accounts.models import User
from portal.processes import SECOND_ROBOT


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
                )
                created.append((username, password))
        for username, password in created:
            self.stdout.write(f"demo user created: {username} / password: {password}")
        if not created:
            self.stdout.write("demo users already exist (passwords were printed when created)")
