"""What the calendar hears live of the changes that are not events: maintenance windows made,
changed or deleted, a booking deleted (with its owner's account), a robot made or taken out of
service or put back (the events' pushes: ``portal/web/handlers.py``).

Connected by ``WebConfig.ready`` to the models' saves (by model label, so this module loads
before the models do). A save of any process tells the calendars open anywhere; the
event carries no booking's details — each page reads what its user may see.
"""

from __future__ import annotations

from typing import Any

from core.live import CALENDAR, hold_publish, publish_on_commit


def calendar_changed(sender: Any, **kwargs: Any) -> None:
    publish_on_commit(CALENDAR, {"type": "changed"})


def resource_saved(sender: Any, instance: Any, created: bool = False, **kwargs: Any) -> None:
    """A new resource, or one an admin took out of service or put back (lifting a hold)."""
    if created:
        calendar_changed(sender)
    else:
        hold_publish(instance)
