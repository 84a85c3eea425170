"""The runs' reactions to events (``core.events.dispatch``): the e-mails of a run's bad end and
of a robot's hold. Imported when the app is ready (``RunsConfig.ready``)."""

from __future__ import annotations

from core.events.dispatch import handler
from core.events.models import Event
from portal.runs import notifications
from portal.runs.models import SelfCheck
from portal.runs.services import self_check


@handler("run-owner-mail", types=["run.failed", "run.interrupted"])
def run_owner_mail(event: Event) -> None:
    notifications.run_owner_notify(run_id=event.payload["run"])


@handler("robot-hold-mail", types=["robot.held"])
def robot_hold_mail(event: Event) -> None:
    notifications.robot_hold_notify(resource_name=event.payload["resource"])


def _self_checks_pending() -> bool:
    """Only while a self-check waits for its run do runs' ends wake this handler (most runs'
    data wake no one)."""
    return SelfCheck.objects.filter(state=SelfCheck.State.PENDING).exists()


@handler(
    "self-check",
    types=["run.data_ready", "run.failed", "run.cancelled"],
    active=_self_checks_pending,
)
def self_check_judge(event: Event) -> None:
    """A self-check's run ended: judge its figures, or say it did not run (a run that ended
    with samples has its ``run.data_ready``; one that failed without any, none)."""
    if event.type == "run.data_ready":
        self_check.self_check_evaluate(run_id=event.payload["run"])
    else:
        self_check.self_check_not_run(run_id=event.payload["run"], state=event.type[len("run.") :])
