"""Create the testbed's resources, once: the mobile node and the fixed nodes.

For a real installation (``make run`` uses ``demo_setup``, which also makes demo users).
Existing resources are left as they are: change them in the admin.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from django.core.management.base import BaseCommand, CommandError, CommandParser

from bookings.services import (
    TestbedSpec,
    fixed_node_names_from_scheduler,
    testbed_resources_ensure,
)
from core.errors import DomainError


class Command(BaseCommand):
    help = "Create the mobile node and the fixed nodes that do not exist yet (idempotent)."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument(
            "--agent-url", required=True, help="the mobile node's base-station agent"
        )
        parser.add_argument("--mobile-name", default="mobile-1")
        parser.add_argument("--fixed-nodes", type=int, default=24)
        parser.add_argument("--max-velocity-mps", type=float, default=2.0)
        parser.add_argument("--max-accel-mps2", type=float, default=1.0)

    def handle(self, *args: Any, **options: Any) -> None:
        spec = TestbedSpec(
            agent_url=options["agent_url"],
            mobile_name=options["mobile_name"],
            fixed_nodes=options["fixed_nodes"],
            max_velocity_mps=options["max_velocity_mps"],
            max_accel_mps2=options["max_accel_mps2"],
        )
        try:
            # With a scheduler, the fixed nodes are the ones it leases.
            spec = replace(spec, fixed_node_names=fixed_node_names_from_scheduler())
            created = testbed_resources_ensure(spec)
        except DomainError as exc:
            raise CommandError(exc.message) from exc
        for name in created:
            self.stdout.write(f"created {name}")
        self.stdout.write(
            f"{len(created)} resource(s) created; the others existed and were left as they are."
        )
