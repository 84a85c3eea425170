"""What the pages hear live of the events (``core.events.dispatch``): a run's every state and
each change of its measurement series on its stream, a robot's hold and release on its console
and the calendars, a booking made, moved, decided or cancelled on the calendars
(``core.live``). Imported when the app is ready (``WebConfig.ready``).

Its passes run in the runs worker (``queue``), so a push never waits behind an e-mail; new to
a database, it starts after the events already there. What is not an event is pushed where it
happens: a run's new samples (``portal.runs.services.collection``), a robot's health status
(``portal.runs.services.health``), a maintenance window or a robot's service changed
(``portal.web.signals``).
"""

from __future__ import annotations

import logging

from bookings.models import Resource
from core import live
from core.events.catalogue import EVENT_TYPES, RUN_STATES
from core.events.dispatch import handler
from core.events.models import Event
from portal.processes import RUNS_QUEUE
from portal.runs.states import RUN_END_STATES, RunState

logger = logging.getLogger(__name__)

RUN_STATE_TYPES = [f"run.{state}" for state in RUN_STATES]
ROBOT_HOLD_TYPES = ["robot.held", "robot.released"]
RESERVATION_TYPES = sorted(
    name
    for name in EVENT_TYPES
    if name.startswith("reservation.") and name not in ("reservation.starting_soon",)
)


@handler(
    "live-pushes",
    types=[*RUN_STATE_TYPES, "run.measured", *ROBOT_HOLD_TYPES, *RESERVATION_TYPES],
    queue=RUNS_QUEUE,
    from_end=True,
)
def live_push(event: Event) -> None:
    """Publish what the event changed; a bus that is down loses the push, never the event
    (``core.live``: the pages catch up by reading their data)."""
    payload = event.payload
    if event.type in RUN_STATE_TYPES:
        state = payload["state"]
        live.publish(
            live.run_channel(payload["run"]),
            {
                "type": "state",
                "state": state,
                "label": RunState(state).label,
                "reason": payload["reason"],
                "live": state not in RUN_END_STATES,
            },
        )
    elif event.type == "run.measured":
        # The run page and its roof view read the series again (a batch pushed during the run).
        live.publish(
            live.run_channel(payload["run"]),
            {
                "type": "measurements",
                "series": payload["series"],
                "change": payload["change"],
                "points": payload["points"],
            },
        )
    elif event.type in ROBOT_HOLD_TYPES:
        resource = Resource.objects.filter(name=payload["resource"]).first()
        if resource is None:
            logger.info("robot %s is gone: no push of its %s", payload["resource"], event.type)
            return
        hold = live.hold_event(resource)  # as it is now: the newest numbers
        live.publish(live.CALENDAR, hold)
        live.publish(live.robot_channel(resource.name), hold)
    else:
        live.publish(live.CALENDAR, {"type": "changed"})
