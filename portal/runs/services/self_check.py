"""A robot's self-check: booked like any run, judged when its data are in, held if worn.

An admin books it (the console, the REST API, or ``amazing``), or the nightly schedule does
for the admins; either way through ``reservation_create``, the one door of every booking with
a run, so the calendar, the quotas' exemptions and the audit treat it as any booking. When the
run's samples are in (the ``run.data_ready`` event), :func:`self_check_evaluate` reads the
figures (``portal.runs.self_check``), judges them against the limits and the robot's baseline,
and on a problem holds the robot with the reason (``resource_hold``: its ``robot.held`` event
tells the staff). The first passing check of a robot becomes its baseline; an admin may choose
another (:func:`self_check_baseline_set`).
"""

from __future__ import annotations

import logging
from datetime import datetime, time, timedelta
from typing import Final
from zoneinfo import ZoneInfo

from django.conf import settings
from django.db import transaction
from django.utils import timezone

from bookings.choices import Channel
from bookings.models import Resource
from bookings.selectors import resource_first_free
from bookings.services import resource_hold
from core.accounts.models import User
from core.audit.services import audit_record
from core.errors import Conflict, DomainError, InvalidInput, NotAllowed
from portal.experiments.models import Experiment
from portal.runs import queries
from portal.runs.models import Run, SelfCheck, SelfCheckBaseline, SelfCheckSchedule
from portal.runs.selectors import robot_for_programs
from portal.runs.self_check import (
    NotMeasurable,
    Program,
    self_check_figures,
    self_check_judge,
    self_check_program,
)

# The module: booking with a run imports the tasks, whose beat task books through here.
from portal.runs.services import reservations as with_run
from portal.runs.services.dry_run import DEFAULT_MAX_ACCEL_MPS2, DEFAULT_RAIL_LENGTH_M
from portal.runs.states import RunState

logger = logging.getLogger(__name__)

# The booking's end after the program's: the robot's ramp down and the run's close.
END_MARGIN_S: Final = 30
# How far ahead the first free slot is looked for.
SEARCH_HORIZON: Final = timedelta(days=7)
# A hold this check made starts with this (an admin's lift, or a passing check, says why).
HOLD_PREFIX: Final = "self-check: "
# A schedule books its day's check this long before its time.
SCHEDULE_AHEAD: Final = timedelta(hours=12)


def self_check_plan(resource: Resource) -> Program:
    """The check's program for ``resource`` with its limits and rail as the portal knows them
    (a rail never measured: the default one's length)."""
    robot = robot_for_programs(resource)
    velocity = robot["max_velocity_mps"]
    if velocity is None or velocity <= 0:
        raise InvalidInput.on_field("resource", f"{resource.name} has no velocity limit to check.")
    return self_check_program(
        max_velocity_mps=velocity,
        max_accel_mps2=robot["max_accel_mps2"] or DEFAULT_MAX_ACCEL_MPS2,
        lap_m=settings.SELF_CHECK_LAP_M or robot["rail_length_m"] or DEFAULT_RAIL_LENGTH_M,
    )


def self_check_book(
    *,
    resource: Resource,
    by: User,
    start_at: datetime | None = None,
    earliest: datetime | None = None,
    via: Channel = Channel.API,
    ip: str | None = None,
    now: datetime | None = None,
) -> SelfCheck:
    """Book ``resource``'s self-check at ``start_at``, or in its first free slot from
    ``earliest`` (and at least ``SELF_CHECK_LEAD_S`` from now); only admins. Refused as any
    booking is (a slot taken, a robot out of booking)."""
    if not by.is_testbed_admin:
        raise NotAllowed("Only admins start a robot's self-check.")
    if not resource.is_mobile:
        raise InvalidInput.on_field("resource", f"{resource.name} is not a robot.")
    now = now or timezone.now()
    program = self_check_plan(resource)
    length = timedelta(
        seconds=round(sum(float(s["duration_s"]) for s in program.segments) + END_MARGIN_S)
    )
    if start_at is None:
        soonest = now + timedelta(seconds=settings.SELF_CHECK_LEAD_S)
        slot = resource_first_free(
            resource=resource,
            earliest=max(soonest, earliest or soonest),
            length=length,
            horizon=SEARCH_HORIZON,
        )
        if slot is None:
            raise Conflict(f"{resource.name} has no free slot for a self-check within a week.")
        start_at = slot[0]
    title = f"Self-check of {resource.name}"
    with transaction.atomic():
        experiment = _experiment(by, title, program)
        reservation = with_run.reservation_create(
            owner=by,
            resource=resource,
            start_at=start_at,
            end_at=start_at + length,
            experiment=experiment,
            title=title,
            by=by,
            ip=ip,
            now=now,
            via=via,
        )
        check = SelfCheck.objects.create(
            run=Run.objects.get(reservation=reservation),
            resource=resource,
            check_velocity_mps=program.check_velocity_mps,
            accel_mps2=program.accel_mps2,
            lap_m=program.lap_m,
        )
    return check


def _experiment(by: User, title: str, program: Program) -> Experiment:
    """The admin's experiment of the robot's check, its program brought up to date: one per
    admin and robot, not one a night in their list."""
    experiment = Experiment.objects.filter(owner=by, title=title).order_by("-created_at").first()
    if experiment is None:
        return Experiment.objects.create(owner=by, title=title, segments=program.segments)
    if experiment.segments != program.segments:
        experiment.segments = program.segments
        experiment.save(update_fields=["segments", "updated_at"])
    return experiment


def _program_of(check: SelfCheck) -> Program:
    """The program the check's run drove, rebuilt from its parameters (the same function
    made it: a run whose segments differ was not made by this version)."""
    program = self_check_program(
        max_velocity_mps=check.check_velocity_mps,
        max_accel_mps2=check.accel_mps2,
        lap_m=check.lap_m,
    )
    if program.segments != check.run.segments:
        raise NotMeasurable("its run's program is not the self-check's of this version")
    return program


def self_check_evaluate(*, run_id: int, now: datetime | None = None) -> SelfCheck | None:
    """Judge the self-check of run ``run_id`` once its data are in (None: not a self-check,
    or already judged). Holds the robot when a figure is out of tolerance."""
    now = now or timezone.now()
    with transaction.atomic():
        check = (
            SelfCheck.objects.select_for_update()
            .select_related("run", "resource")
            .filter(run_id=run_id, state=SelfCheck.State.PENDING)
            .first()
        )
        if check is None:
            return None
        run = check.run
        baseline = SelfCheckBaseline.objects.filter(resource=check.resource).first()
        try:
            ended = (run.provenance or {}).get("collected") or {}
            figures = self_check_figures(
                queries.sample_columns(run),
                _program_of(check),
                rail_length_m=run.rail_length_m or DEFAULT_RAIL_LENGTH_M,
                link_loss_pct=(ended.get("link") or {}).get("loss_pct"),
                cpu_temp_c=ended.get("cpu_temp_c_at_end"),
            )
        except NotMeasurable as exc:
            check.state, check.reason = SelfCheck.State.NOT_RUN, str(exc)
        else:
            check.figures = figures.as_dict()
            check.reason = figures.unmeasured
            check.baseline = baseline.figures if baseline is not None else None
            problems = self_check_judge(
                check.figures,
                check_velocity_mps=check.check_velocity_mps,
                accel_mps2=check.accel_mps2,
                baseline=check.baseline,
                unmeasured=figures.unmeasured,
            )
            check.problems = [p.text for p in problems]
            check.state = SelfCheck.State.FAILED if problems else SelfCheck.State.PASSED
        check.evaluated_at = now
        check.save(
            update_fields=["state", "figures", "problems", "baseline", "reason", "evaluated_at"]
        )
        if check.state == SelfCheck.State.PASSED and baseline is None:
            SelfCheckBaseline.objects.create(
                resource=check.resource, figures=check.figures, source=check
            )
        if check.state == SelfCheck.State.FAILED:
            resource_hold(
                resource_id=check.resource_id, reason=HOLD_PREFIX + "; ".join(check.problems)
            )
        logger.info(
            "self-check %s of %s: %s %s",
            check.pk,
            check.resource.name,
            check.state,
            "; ".join(check.problems) or check.reason,
        )
    return check


def self_check_not_run(*, run_id: int, state: str) -> None:
    """The check's run ended without data (failed, cancelled): the check says so."""
    SelfCheck.objects.filter(run_id=run_id, state=SelfCheck.State.PENDING).update(
        state=SelfCheck.State.NOT_RUN,
        reason=f"its run {RunState(state).label}",
        evaluated_at=timezone.now(),
    )


def self_check_baseline_set(*, check: SelfCheck, by: User, ip: str | None = None) -> None:
    """Judge ``check.resource``'s next checks against ``check``'s figures; only admins, only
    a check whose figures were all measured. Audited."""
    if not by.is_testbed_admin:
        raise NotAllowed("Only admins set a robot's self-check baseline.")
    if check.state not in (SelfCheck.State.PASSED, SelfCheck.State.FAILED) or any(
        value is None for value in check.figures.values()
    ):
        raise InvalidInput.on_field("check", "Only a check with every figure measured can be one.")
    with transaction.atomic():
        SelfCheckBaseline.objects.update_or_create(
            resource=check.resource,
            defaults={"figures": check.figures, "source": check, "set_by": by},
        )
        audit_record(
            actor=by,
            action="robot.self_check_baseline",
            target=check.resource,
            ip=ip,
            check=check.pk,
            figures=check.figures,
        )


# --- every day ---------------------------------------------------------------------------------


def self_check_schedule_set(
    *, resource: Resource, by: User, at: time | None, ip: str | None = None
) -> SelfCheckSchedule | None:
    """Book ``resource``'s self-check every day at ``at`` (the testbed's wall-clock time), or
    stop (None); only admins. Audited."""
    if not by.is_testbed_admin:
        raise NotAllowed("Only admins schedule a robot's self-check.")
    if not resource.is_mobile:
        raise InvalidInput.on_field("resource", f"{resource.name} is not a robot.")
    with transaction.atomic():
        schedule: SelfCheckSchedule | None = None
        if at is None:
            SelfCheckSchedule.objects.filter(resource=resource).delete()
        else:
            schedule, _ = SelfCheckSchedule.objects.update_or_create(
                resource=resource, defaults={"at": at, "set_by": by}
            )
        audit_record(
            actor=by,
            action="robot.self_check_schedule",
            target=resource,
            ip=ip,
            at=at.isoformat(timespec="minutes") if at is not None else None,
        )
    return schedule


def _next_at(schedule: SelfCheckSchedule, now: datetime) -> datetime:
    """The schedule's next time on the testbed's wall clock from ``now`` (a time in the hour
    a clock change skips is read before the change: the hour after it)."""
    zone = ZoneInfo(settings.TIME_ZONE)
    local = now.astimezone(zone)
    today = datetime.combine(local.date(), schedule.at, tzinfo=zone)
    return (
        today
        if today >= now
        else datetime.combine(local.date() + timedelta(days=1), schedule.at, tzinfo=zone)
    )


def self_checks_book_scheduled(*, now: datetime | None = None) -> list[SelfCheck]:
    """Book the day's check of each schedule whose time comes within SCHEDULE_AHEAD, once per
    day; what was booked. A schedule acts for the admin who set it (with their second factor)
    while they keep the staff role; a day's check that cannot be booked (the robot out of
    booking, no free slot) is logged and that day passed over."""
    now = now or timezone.now()
    booked: list[SelfCheck] = []
    for schedule in SelfCheckSchedule.objects.select_related("resource", "set_by"):
        due = _next_at(schedule, now)
        if due - now > SCHEDULE_AHEAD or (schedule.booked_for and due <= schedule.booked_for):
            continue
        admin = schedule.set_by
        try:
            if not admin.has_staff_role:
                raise NotAllowed(f"{admin.get_username()}, who set it, is no longer an admin")
            admin.staff_verified = True  # the schedule is their standing instruction
            booked.append(
                self_check_book(
                    resource=schedule.resource,
                    by=admin,
                    earliest=due,
                    via=Channel.SCHEDULE,
                    now=now,
                )
            )
        except DomainError as exc:
            logger.warning(
                "self-check of %s for %s not booked: %s", schedule.resource.name, due, exc.message
            )
        SelfCheckSchedule.objects.filter(pk=schedule.pk).update(booked_for=due)
    return booked
