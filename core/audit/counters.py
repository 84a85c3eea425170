"""Counters of rare events that any portal process records and ``/metrics`` exposes
(``core.audit.models.EventCount``; ``portal/runs/metrics.py`` reads them).

Each counter has one name here, with its help text; ``event_count`` refuses a name not
listed, so a typo cannot start a new series.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass

from django.db import IntegrityError, transaction
from django.db.models import F

from core.audit.models import EventCount

# name (without the amazing_ prefix and _total suffix) -> help text
COUNTERS: dict[str, str] = {
    "run_staging_failures": (
        "Failed attempts to stage a run on its agent, by robot and outcome "
        "(retrying: the agent was out of reach, tried again; failed: the run failed)."
    ),
    "scheduler_link_errors": "Sweeps of the testbed scheduler's leases that failed.",
    "robot_holds": "Robots taken out of booking by their health check, by robot.",
}


@dataclass(frozen=True)
class CounterValue:
    name: str
    labels: dict[str, str]
    value: int


def event_count(name: str, **labels: str) -> None:
    """Add one to the counter ``name`` with ``labels``; safe from any process at once."""
    if name not in COUNTERS:
        raise ValueError(f"unknown counter {name!r}")
    key = json.dumps(labels, sort_keys=True)
    with transaction.atomic():
        if EventCount.objects.filter(name=name, labels=key).update(value=F("value") + 1):
            return
        try:
            with transaction.atomic():
                EventCount.objects.create(name=name, labels=key, value=1)
        except IntegrityError:  # another process created it a moment ago
            EventCount.objects.filter(name=name, labels=key).update(value=F("value") + 1)


def event_counts() -> Iterator[CounterValue]:
    for name, labels, value in EventCount.objects.order_by("name", "labels").values_list(
        "name", "labels", "value"
    ):
        yield CounterValue(name=name, labels=json.loads(labels), value=value)
