"""What the experiment builder shows beside the fields: the robots the user may book, with
the limits booking will hold a program to, and their rails' lengths as last measured."""

from __future__ import annotations

from typing import Any

from django.conf import settings

from basestation.contract import MAX_SEGMENTS
from bookings.rules import velocity_limit
from bookings.selectors import mobiles_bookable
from portal.runs.models import Run


def builder_context() -> dict[str, Any]:
    robots = []
    for robot in mobiles_bookable():
        limit = velocity_limit(robot)
        accel = robot.max_accel_mps2
        if robot.agent_max_accel_mps2 is not None:
            accel = (
                robot.agent_max_accel_mps2
                if accel is None
                else min(accel, robot.agent_max_accel_mps2)
            )
        # The rail is measured by the robot on each run; its latest run says it best.
        rail_m = (
            Run.objects.filter(resource=robot, rail_length_m__isnull=False)
            .order_by("-start_at")
            .values_list("rail_length_m", flat=True)
            .first()
        )
        robots.append(
            {
                "name": robot.name,
                "max_velocity_mps": limit.mps if limit is not None else None,
                "max_accel_mps2": accel,
                "rail_length_m": rail_m,
            }
        )
    return {
        "robots": robots,
        "max_program_s": settings.RESERVATION_MAX_S,
        "max_segments": MAX_SEGMENTS,
    }
