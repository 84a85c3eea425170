"""Writes for reservations: every capacity check runs under a lock of the resource row."""

from __future__ import annotations

import logging
from datetime import datetime, timedelta
from functools import partial

from django.conf import settings
from django.db import transaction
from django.utils import timezone

from bookings.choices import ReservationState
from bookings.models import Reservation, Resource
from bookings.selectors import reservations_overlapping
from portal.accounts.models import User
from portal.errors import Conflict, InvalidInput, NotAllowed
from portal.experiments.choices import RunState
from portal.experiments.models import Experiment, Run
from portal.experiments.services import run_create, run_transition, segments_validate

logger = logging.getLogger(__name__)


def _aware(value: datetime, field: str) -> datetime:
    if timezone.is_naive(value):
        raise InvalidInput.on_field(field, "Give a time zone (for example 2026-05-01T10:00+01:00).")
    return value


def reservation_create(
    *,
    owner: User,
    resource: Resource,
    start_at: datetime,
    end_at: datetime,
    experiment: Experiment | None = None,
    now: datetime | None = None,
) -> Reservation:
    """Book ``resource`` for ``[start_at, end_at)``; on a mobile node, also schedule the run."""
    now = now or timezone.now()
    start_at = _aware(start_at, "start_at")
    end_at = _aware(end_at, "end_at")
    if end_at <= start_at:
        raise InvalidInput.on_field("end_at", "The end must be after the start.")
    if start_at < now:
        raise InvalidInput.on_field("start_at", "The start is in the past.")
    max_length = timedelta(seconds=settings.RESERVATION_MAX_S)
    if end_at - start_at > max_length:
        raise InvalidInput.on_field(
            "end_at", f"A reservation lasts at most {max_length.total_seconds() / 3600:g} h."
        )
    if not resource.enabled:
        raise InvalidInput.on_field("resource", f"{resource.name} is out of service.")
    if resource.is_mobile:
        if experiment is None:
            raise InvalidInput.on_field("experiment", "Choose the experiment the robot will run.")
        if experiment.owner_id != owner.pk and not owner.is_testbed_admin:
            raise NotAllowed.on_field("experiment", "That experiment is not yours.")
        segments_validate(experiment.segments, max_velocity_mps=resource.max_velocity_mps)
        length_s = (end_at - start_at).total_seconds()
        if experiment.duration_s > length_s:
            raise InvalidInput.on_field(
                "end_at",
                f"The experiment lasts {experiment.duration_s:g} s but the reservation only "
                f"{length_s:g} s.",
            )
    elif experiment is not None:
        raise InvalidInput.on_field("experiment", "Only mobile nodes run experiments.")

    with transaction.atomic():
        # Serialise bookings of one resource: the overlap check and the insert cannot interleave.
        Resource.objects.select_for_update().filter(pk=resource.pk).first()
        clash = reservations_overlapping(
            resource=resource, start_at=start_at, end_at=end_at
        ).first()
        if clash is not None:
            local = timezone.localtime
            raise Conflict.on_field(
                "start_at",
                f"{resource.name} is already booked from {local(clash.start_at):%Y-%m-%d %H:%M} "
                f"to {local(clash.end_at):%H:%M}.",
            )
        reservation = Reservation(resource=resource, owner=owner, start_at=start_at, end_at=end_at)
        reservation.full_clean()
        reservation.save()
        if experiment is not None:
            run_create(reservation=reservation, experiment=experiment)
    logger.info("reservation %s created by %s", reservation.pk, owner.username)
    return reservation


def reservation_cancel(*, reservation: Reservation, by: User, reason: str = "") -> Reservation:
    """Cancel a reservation and its run; a staged or running run is withdrawn from its agent."""
    from bookings.tasks import run_unstage

    if reservation.owner_id != by.pk and not by.is_testbed_admin:
        raise NotAllowed("Only the owner or an admin can cancel this reservation.")
    with transaction.atomic():
        locked = Reservation.objects.select_for_update().get(pk=reservation.pk)
        if locked.state != ReservationState.CONFIRMED:
            raise Conflict(f"The reservation is already {locked.state}.")
        locked.state = ReservationState.CANCELLED
        locked.save(update_fields=["state", "updated_at"])
        why = reason or f"cancelled by {by.username}"
        run = Run.objects.filter(reservation=locked).first()
        if (
            run is not None
            and not run_transition(
                run_id=run.pk,
                from_states=[RunState.SCHEDULED],
                to_state=RunState.CANCELLED,
                reason=why,
            )
            and run.state in (RunState.STAGED, RunState.RUNNING)
        ):
            # The agent decides: a staged run is cancelled there, a running one is aborted
            # (the robot ramps to zero) and its data collected as an interrupted run.
            transaction.on_commit(partial(run_unstage.delay, run.pk))
    logger.info("reservation %s cancelled by %s", reservation.pk, by.username)
    return locked
