"""``/metrics``: how far each handler of events is behind (``amazing_event_handler_backlog``).

A backlog that stays above zero says the worker that runs the handler's passes (the mail
worker; the runs worker for the live pushes) is down or stuck, or that the handler fails on an
event and is handed it again at every pass (its error is in that worker's log).
docs/operations.md has the alert.
"""

from __future__ import annotations

from collections.abc import Iterator

from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector

from core.events import registry
from core.events.models import Event, EventCursor
from core.events.sequence import events_sequence


def handler_backlogs() -> dict[str, int]:
    """Each handler's events not handled yet: of its types, after its cursor (none for a
    handler that has nothing to do now: its cursor moves past them at its next pass)."""
    events_sequence()  # what has committed, numbered, as every reader does
    cursors = dict(EventCursor.objects.values_list("handler", "position"))
    backlogs: dict[str, int] = {}
    for name, registration in sorted(registry.handlers().items()):
        if registration.active is not None and not registration.active():
            backlogs[name] = 0
            continue
        if registration.from_end and name not in cursors:
            backlogs[name] = 0  # its first pass starts it after what is there
            continue
        backlogs[name] = Event.objects.filter(
            position__gt=cursors.get(name, 0), type__in=registration.types
        ).count()
    return backlogs


class EventsCollector(Collector):
    def collect(self) -> Iterator[GaugeMetricFamily]:
        backlog = GaugeMetricFamily(
            "amazing_event_handler_backlog",
            "Events a handler has not handled yet (the e-mails, webhooks, counters).",
            labels=["handler"],
        )
        for name, count in handler_backlogs().items():
            backlog.add_metric([name], count)
        yield backlog
