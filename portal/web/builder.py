"""What the experiment builder shows beside the fields: the robots the user may book, with
the limits booking will hold a program to, and their rails' lengths as last measured."""

from __future__ import annotations

from typing import Any

from django.conf import settings

from basestation.contract import MAX_SEGMENTS
from portal.runs.selectors import robots_for_programs


def builder_context() -> dict[str, Any]:
    return {
        "robots": robots_for_programs(),
        "max_program_s": settings.RESERVATION_MAX_S,
        "max_segments": MAX_SEGMENTS,
    }
