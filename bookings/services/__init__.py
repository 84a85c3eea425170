"""The booking services: every write to reservations, resources, blackouts and quota
policies, and the live check of a booking. Callers import from here.

- ``reservations``: the live check (``reservation_check``) and booking, moving, attaching a
  program to, cancelling, deciding and completing a reservation; the booking locks
  (``_lock``) and the lease on the testbed's scheduler held with a booking.
- ``resources``: a resource in or out of service, the health check's holds on a robot, and
  what the health check learns of its agent (unreachable since when, the limits it reports).
- ``blackouts``: maintenance windows, and the bookings they overlap flagged.
- ``quota_policies``: quota policies created and changed, audited.
- ``setup``: the resources of a testbed installation (``TestbedSpec``), named after the
  testbed's scheduler when one is configured.

Every check that guards capacity runs inside one transaction under row locks taken in a
fixed order (the user, then the resources by id), so concurrent bookings are decided one at
a time; on PostgreSQL an exclusion constraint backs the overlap check. What may be booked,
moved or cancelled is decided in ``bookings.rules``; these functions raise its first problem.
"""

from bookings.services.blackouts import blackout_create
from bookings.services.quota_policies import QUOTA_FIELDS, quota_policy_save
from bookings.services.reservations import (
    ReservationCheck,
    reservation_cancel,
    reservation_check,
    reservation_complete,
    reservation_create,
    reservation_decide,
    reservation_program_attach,
    reservation_reschedule,
)
from bookings.services.resources import (
    AGENT_NOT_CONFIGURED,
    AgentLimits,
    resource_agent_reachable,
    resource_agent_unreachable,
    resource_hold,
    resource_hold_lift,
    resource_record_agent_limits,
    resource_set_service,
    robot_event,
)
from bookings.services.setup import (
    TestbedSpec,
    fixed_node_names_from_scheduler,
    testbed_resources_ensure,
)

__all__ = [
    "AGENT_NOT_CONFIGURED",
    "QUOTA_FIELDS",
    "AgentLimits",
    "ReservationCheck",
    "TestbedSpec",
    "blackout_create",
    "fixed_node_names_from_scheduler",
    "quota_policy_save",
    "reservation_cancel",
    "reservation_check",
    "reservation_complete",
    "reservation_create",
    "reservation_decide",
    "reservation_program_attach",
    "reservation_reschedule",
    "resource_agent_reachable",
    "resource_agent_unreachable",
    "resource_hold",
    "resource_hold_lift",
    "resource_record_agent_limits",
    "resource_set_service",
    "robot_event",
    "testbed_resources_ensure",
]
