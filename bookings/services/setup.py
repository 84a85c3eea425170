"""Testbed set-up: the resources of an installation (one mobile node and the fixed nodes),
named after the testbed's scheduler when one is configured."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from django.core.exceptions import ValidationError
from django.db import transaction

from bookings.choices import ResourceKind
from bookings.leases import scheduler_client, scheduler_enabled
from bookings.models import Resource
from bookings.scheduler import SchedulerError
from core.errors import InvalidInput

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class TestbedSpec:
    """The resources of a testbed installation: one mobile node and the fixed nodes."""

    agent_url: str
    mobile_name: str = "mobile-1"
    fixed_nodes: int = 24
    max_velocity_mps: float = 2.0
    max_accel_mps2: float = 1.0
    # The name of the agent's token in AGENT_TOKENS ("default" is AGENT_TOKEN).
    agent_token_name: str = "default"  # noqa: S105 - a name, not the secret
    mobile_description: str = "Rail robot around the roof of IT building 1"
    # The fixed nodes by name, as the testbed's scheduler lists them; ``node-01`` … otherwise.
    fixed_node_names: tuple[str, ...] = ()

    def fixed_names(self) -> tuple[str, ...]:
        if self.fixed_node_names:
            return self.fixed_node_names
        return tuple(f"node-{i:02d}" for i in range(1, self.fixed_nodes + 1))


def fixed_node_names_from_scheduler() -> tuple[str, ...]:
    """The nodes the testbed's scheduler leases (empty when none is configured)."""
    if not scheduler_enabled():
        return ()
    try:
        with scheduler_client() as scheduler:
            return tuple(node.name for node in scheduler.list_nodes())
    except SchedulerError as exc:
        raise InvalidInput(f"The testbed scheduler did not list its nodes: {exc.message}") from exc


def testbed_resources_ensure(spec: TestbedSpec) -> list[str]:
    """Create whichever of the spec's resources do not exist yet; returns their names.

    Existing ones are left untouched (an admin may have changed them since). Everything is
    checked before anything is written.
    """
    if not 1 <= len(spec.fixed_names()) <= 200:
        raise InvalidInput.on_field("fixed_nodes", "Give between 1 and 200 fixed nodes.")
    for field_name, value in (
        ("max_velocity_mps", spec.max_velocity_mps),
        ("max_accel_mps2", spec.max_accel_mps2),
    ):
        if not (math.isfinite(value) and value > 0):
            raise InvalidInput.on_field(field_name, f"{field_name} must be positive, got {value}.")
    wanted = [
        Resource(
            name=spec.mobile_name,
            kind=ResourceKind.MOBILE,
            description=spec.mobile_description,
            agent_url=spec.agent_url,
            agent_token_name=spec.agent_token_name,
            max_velocity_mps=spec.max_velocity_mps,
            max_accel_mps2=spec.max_accel_mps2,
        ),
        *(
            Resource(
                name=name,
                kind=ResourceKind.FIXED,
                description="Fixed node on the roof of IT building 1",
            )
            for name in spec.fixed_names()
        ),
    ]
    for resource in wanted:
        try:
            resource.full_clean(validate_unique=False)
        except ValidationError as exc:
            raise InvalidInput(f"{resource.name}: {'; '.join(exc.messages)}") from exc
    with transaction.atomic():
        existing = set(
            Resource.objects.filter(name__in=[r.name for r in wanted]).values_list(
                "name", flat=True
            )
        )
        missing = [r for r in wanted if r.name not in existing]
        Resource.objects.bulk_create(missing)
    if missing:
        # One line, not one a resource: `make run` prints it among the start's few lines.
        names = [r.name for r in missing]
        logger.info("%d resources created: %s", len(names), ", ".join(names))
    return [r.name for r in missing]
