"""The runs' reactions to events (``core.events.dispatch``): the e-mails of a run's bad end and
of a robot's hold. Imported when the app is ready (``RunsConfig.ready``)."""

from __future__ import annotations

from core.events.dispatch import handler
from core.events.models import Event
from portal.runs import notifications


@handler("run-owner-mail", types=["run.failed", "run.interrupted"])
def run_owner_mail(event: Event) -> None:
    notifications.run_owner_notify(run_id=event.payload["run"])


@handler("robot-hold-mail", types=["robot.held"])
def robot_hold_mail(event: Event) -> None:
    notifications.robot_hold_notify(resource_name=event.payload["resource"])
