"""E-mails about runs and robots: a run that failed or was interrupted (to its owner), a robot
the health check took out of booking (to the admins).

Each is a reaction to an event (``portal/runs/handlers.py``: ``run.failed``,
``run.interrupted``, ``robot.held``), handed to it once the change committed, at least once
(``core.events.dispatch``): a mail server that fails leaves the event to be handed again.
"""

from __future__ import annotations

import logging

from django.conf import settings
from django.core.mail import send_mail
from django.db.models import QuerySet
from django.utils import timezone

from bookings.choices import ReservationState
from bookings.models import Resource
from core.accounts.models import User
from portal.runs.models import Run
from portal.runs.states import RunState

logger = logging.getLogger(__name__)

TOLD_STATES = (RunState.FAILED, RunState.INTERRUPTED)


def runs_to_tell() -> QuerySet[Run]:
    """Runs that failed or were interrupted. A run whose booking was cancelled or rejected is
    left out: whoever ended it said so already."""
    return Run.objects.filter(state__in=TOLD_STATES).exclude(
        reservation__state__in=[ReservationState.CANCELLED, ReservationState.REJECTED]
    )


def run_message(run: Run) -> tuple[str, str]:
    when = timezone.localtime(run.start_at)
    what = f"“{run.title}” on {run.resource.name}, {when:%Y-%m-%d %H:%M} ({settings.TIME_ZONE})"
    ended = "failed" if run.state == RunState.FAILED else "was interrupted"
    lines = [
        f"Hello {run.reservation.owner.get_username()},",
        "",
        f"your run {what} {ended}: {run.reason}",
    ]
    if run.state == RunState.INTERRUPTED:
        lines += ["", "The data recorded until then is kept: see the run's page and downloads."]
    lines += ["", "— AMazING testbed"]
    return f"Run {ended}: {run.title}", "\n".join(lines)


def run_owner_notify(*, run_id: int) -> int:
    """E-mail the owner of a failed or interrupted run; how many were sent."""
    run = runs_to_tell().select_related("resource", "reservation__owner").filter(pk=run_id).first()
    if run is None:
        return 0  # not an end to tell
    address = run.reservation.owner.email
    if not address:
        logger.warning("run %s: its owner has no address to tell", run.pk)
        return 0
    subject, body = run_message(run)
    return send_mail(subject, body, settings.DEFAULT_FROM_EMAIL, [address])


def robot_hold_message(resource: Resource) -> tuple[str, str]:
    since = timezone.localtime(resource.held_at) if resource.held_at else timezone.localtime()
    body = "\n".join(
        [
            f"{resource.name} was taken out of booking at {since:%Y-%m-%d %H:%M:%S} "
            f"({settings.TIME_ZONE}):",
            "",
            f"    {resource.hold_reason}",
            "",
            "Runs already booked keep their slots. Once the robot is fit again, put it back in",
            "service on its console (the reason is recorded in the audit log).",
            "",
            "— AMazING testbed",
        ]
    )
    return f"{resource.name} out of booking: {resource.hold_reason}", body


def robot_hold_notify(*, resource_name: str) -> int:
    """E-mail the admins about a robot's hold, if it is still held; how many were sent."""
    resource = Resource.objects.exclude(hold_reason="").filter(name=resource_name).first()
    if resource is None:
        return 0  # lifted already: nothing to tell
    admins = sorted(
        set(
            User.objects.filter(is_staff=True, is_active=True)
            .exclude(email="")
            .values_list("email", flat=True)
        )
    )
    if not admins:
        logger.warning("%s held, but no admin has an e-mail address", resource.name)
        return 0
    subject, body = robot_hold_message(resource)
    return send_mail(subject, body, settings.DEFAULT_FROM_EMAIL, admins)
