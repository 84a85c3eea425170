"""The queue's requests: asked for, withdrawn, reordered; the queue paused and resumed. Each
change wakes the allocator (``portal/queue/allocation.py``) after its commit."""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from datetime import datetime, timedelta
from typing import Any

from django.conf import settings
from django.db import transaction
from django.utils import timezone

from bookings.models import Resource
from bookings.rules import FIRST_SEGMENT, aware_utc, velocity_problem
from core.accounts.models import User
from core.audit.services import audit_record
from core.commit_batch import CommitBatch
from core.errors import Conflict, InvalidInput, NotAllowed
from core.pending import queue_once
from portal.experiments.models import Experiment
from portal.queue.events import queue_request_event_record
from portal.queue.models import Campaign, QueueControl, QueueRequest, RequestState
from portal.queue.selectors import queue_control
from portal.queue.tasks import ALLOCATE_SUBJECT, queue_allocate_task

logger = logging.getLogger(__name__)

# A request may wait at most this long between its earliest start and its latest end.
REQUEST_SPAN_MAX = timedelta(days=92)


class _AllocatorWake(CommitBatch):
    """One wake of the allocator per transaction, however many requests it queued (a
    campaign queues them all in one)."""

    def run(self) -> None:
        try:
            queue_once(queue_allocate_task, ALLOCATE_SUBJECT)
        except Exception:
            logger.exception("waking the queue's allocator failed; beat's next pass books")


def allocator_wake() -> None:
    """Wake the allocator once the current transaction commits (at once outside one)."""
    _AllocatorWake.current()


def default_duration_s(experiment: Experiment) -> int:
    """The program's length, rounded up to a whole number of ``QUEUE_SLOT_S`` (a minute)."""
    slot_s = settings.QUEUE_SLOT_S
    return max(slot_s, math.ceil(experiment.duration_s / slot_s) * slot_s)


def queue_request_submit(
    *,
    owner: User,
    experiment: Experiment,
    robot: Resource,
    nodes: Sequence[Resource] = (),
    latest_end_at: datetime,
    earliest_at: datetime | None = None,
    duration_s: int | None = None,
    hours_from: int | None = None,
    hours_to: int | None = None,
    title: str = "",
    ip: str | None = None,
    now: datetime | None = None,
    campaign: Campaign | None = None,
    parameters: dict[str, Any] | None = None,
) -> QueueRequest:
    """Queue ``experiment`` on ``robot`` as soon as possible; the allocator is woken at the
    commit. Refused at once, with nothing queued, when it could never be booked as asked."""
    now = now or timezone.now()
    earliest_at = aware_utc(earliest_at, "earliest_at") if earliest_at is not None else now
    latest_end_at = aware_utc(latest_end_at, "latest_end_at")
    duration_s = duration_s if duration_s is not None else default_duration_s(experiment)
    _refuse_unbookable(
        experiment=experiment,
        robot=robot,
        nodes=nodes,
        earliest_at=earliest_at,
        latest_end_at=latest_end_at,
        duration_s=duration_s,
        hours=(hours_from, hours_to),
        now=now,
    )
    with transaction.atomic():
        request = QueueRequest.objects.create(
            owner=owner,
            experiment=experiment,
            robot=robot,
            title=title or experiment.title,
            duration_s=duration_s,
            earliest_at=earliest_at,
            latest_end_at=latest_end_at,
            hours_from=hours_from,
            hours_to=hours_to,
            campaign=campaign,
            parameters=parameters,
        )
        request.nodes.set(nodes)
        _submit_audit(request, nodes=nodes, ip=ip)
        allocator_wake()
    return request


def _submit_audit(request: QueueRequest, *, nodes: Sequence[Resource], ip: str | None) -> None:
    audit_record(
        actor=request.owner,
        action="queue.submit",
        target=request,
        ip=ip,
        experiment=request.experiment_id,
        robot=request.robot.name,
        nodes=[n.name for n in nodes],
        duration_s=request.duration_s,
        earliest_at=request.earliest_at.isoformat(),
        latest_end_at=request.latest_end_at.isoformat(),
    )


def _refuse_unbookable(
    *,
    experiment: Experiment,
    robot: Resource,
    nodes: Sequence[Resource],
    earliest_at: datetime,
    latest_end_at: datetime,
    duration_s: int,
    hours: tuple[int | None, int | None],
    now: datetime,
) -> None:
    if not robot.is_mobile:
        raise InvalidInput.on_field("robot", f"{robot.name} is not a mobile node.")
    if any(node.is_mobile for node in nodes):
        raise InvalidInput.on_field("nodes", "Only fixed nodes go with the robot.")
    if duration_s <= 0:
        raise InvalidInput.on_field("duration_s", "The duration must be positive.")
    if duration_s > settings.RESERVATION_MAX_S:
        raise InvalidInput.on_field(
            "duration_s", f"A reservation lasts at most {settings.RESERVATION_MAX_S:g} s."
        )
    if experiment.duration_s > duration_s:
        raise InvalidInput.on_field(
            "duration_s",
            f"The experiment lasts {experiment.duration_s:g} s but the request only "
            f"{duration_s} s.",
        )
    if latest_end_at <= max(earliest_at, now) + timedelta(seconds=duration_s):
        raise InvalidInput.on_field(
            "latest_end_at", "The latest end leaves no room for the run after the earliest start."
        )
    if latest_end_at - earliest_at > REQUEST_SPAN_MAX:
        raise InvalidInput.on_field(
            "latest_end_at",
            f"A request may wait at most {REQUEST_SPAN_MAX.days} days between its earliest "
            "start and its latest end.",
        )
    hours_from, hours_to = hours
    if (hours_from is None) != (hours_to is None):
        raise InvalidInput.on_field("hours_to", "Give both allowed hours, or neither.")
    if (
        hours_from is not None
        and hours_to is not None
        and (not (0 <= hours_from <= 23 and 1 <= hours_to <= 24) or hours_from == hours_to % 24)
    ):
        raise InvalidInput.on_field(
            "hours_to", "Allowed hours run from 0-23 to 1-24, and not from an hour to itself."
        )
    for index, velocity_mps in enumerate(experiment.velocities_mps, start=FIRST_SEGMENT):
        why = velocity_problem(resource=robot, velocity_mps=velocity_mps)
        if why is not None:
            raise InvalidInput.on_field("experiment", f"Segment {index}: {why}")


def queue_request_cancel(
    *, request: QueueRequest, by: User, reason: str = "", ip: str | None = None
) -> QueueRequest:
    """Withdraw a waiting request at once (its owner or an admin). A booked one is a booking
    like any other: cancel its reservation."""
    if request.owner_id != by.pk and not by.is_testbed_admin:
        raise NotAllowed("Only the owner or an admin cancels a request.")
    with transaction.atomic():
        locked = QueueRequest.objects.select_for_update().get(pk=request.pk)
        if locked.state != RequestState.WAITING:
            raise Conflict(
                f"The request is {locked.state}: "
                + (
                    f"cancel its reservation {locked.reservation_id} instead."
                    if locked.state == RequestState.BOOKED
                    else "only a waiting request can be cancelled."
                )
            )
        locked.state = RequestState.CANCELLED
        locked.reason = reason or f"cancelled by {by.get_username()}"
        locked.save(update_fields=["state", "reason", "updated_at"])
        audit_record(actor=by, action="queue.cancel", target=locked, reason=reason, ip=ip)
        queue_request_event_record("queue.cancelled", locked)
    return locked


def queue_pause(*, by: User, reason: str, ip: str | None = None) -> QueueControl:
    return _queue_switch(by=by, paused=True, reason=reason, ip=ip)


def queue_resume(*, by: User, reason: str = "", ip: str | None = None) -> QueueControl:
    return _queue_switch(by=by, paused=False, reason=reason, ip=ip)


def _queue_switch(*, by: User, paused: bool, reason: str, ip: str | None) -> QueueControl:
    if not by.is_testbed_admin:
        raise NotAllowed("Only an admin pauses or resumes the queue.")
    if paused and not reason.strip():
        raise InvalidInput.on_field("reason", "Say why the queue is paused.")
    queue_control()  # the row exists
    with transaction.atomic():
        control = QueueControl.objects.select_for_update().get(pk=1)
        control.paused = paused
        control.reason = reason.strip()
        control.changed_by = by
        control.changed_at = timezone.now()
        control.save()
        audit_record(
            actor=by,
            action="queue.pause" if paused else "queue.resume",
            target=control,
            reason=reason,
            ip=ip,
        )
        if not paused:
            allocator_wake()
    return control


def queue_request_reorder(
    *, request: QueueRequest, priority: int, by: User, reason: str, ip: str | None = None
) -> QueueRequest:
    """An admin moves a waiting request ahead of (a higher ``priority``) or behind the
    fair-share order, saying why (audited)."""
    if not by.is_testbed_admin:
        raise NotAllowed("Only an admin reorders the queue.")
    if not reason.strip():
        raise InvalidInput.on_field("reason", "Say why the order changes.")
    if abs(priority) > 1000:
        raise InvalidInput.on_field("priority", "A priority lies between -1000 and 1000.")
    with transaction.atomic():
        locked = QueueRequest.objects.select_for_update().get(pk=request.pk)
        if locked.state != RequestState.WAITING:
            raise Conflict(f"The request is {locked.state}: only a waiting one is reordered.")
        before = locked.priority
        locked.priority = priority
        locked.save(update_fields=["priority", "updated_at"])
        audit_record(
            actor=by,
            action="queue.reorder",
            target=locked,
            reason=reason,
            ip=ip,
            priority_before=before,
            priority=priority,
        )
        allocator_wake()
    return locked
