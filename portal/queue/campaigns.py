"""Campaigns: a sweep's runs made into experiments and queued requests in one transaction
(all or nothing), through the same services as a single request; paused, resumed and
cancelled by their owner (or an admin)."""

from __future__ import annotations

from collections import Counter
from typing import Any

from django.db import transaction
from django.utils import timezone
from django.utils.dateparse import parse_datetime

from bookings.choices import Channel
from bookings.rules import velocity_problem
from bookings.selectors import resources_bookable
from core.accounts.models import User
from core.audit.services import audit_record
from core.errors import Conflict, InvalidInput, NotAllowed
from core.events.services import event_record
from portal.experiments.services import experiment_create
from portal.queue.models import Campaign, CampaignState, QueueRequest, RequestState
from portal.queue.services import allocator_wake, queue_request_cancel, queue_request_submit
from portal.queue.sweep import Sweep, sweep_parse
from portal.runs.services import reservations as with_run
from portal.runs.states import RUN_END_STATES, RunState


def _instant(field: str, value: Any) -> Any:
    # The API checked it as RFC 3339 (CampaignInput); a service caller gets the same rule's
    # essentials: an instant, with its offset.
    try:
        parsed = parse_datetime(value) if isinstance(value, str) else None
    except ValueError:
        parsed = None
    if parsed is None or parsed.tzinfo is None:
        raise InvalidInput(
            f"{field}: give an instant with its offset, such as 2027-05-01T10:00:00+01:00",
            fields={field: ["An instant with its offset, such as 2027-05-01T10:00:00+01:00."]},
        )
    return parsed


def campaign_create(*, owner: User, spec: Any, ip: str | None = None) -> Campaign:
    """Queue every run of the campaign file ``spec``, or nothing: a file with anything unknown,
    too many runs or a run the robot could not make is refused with the field it concerns."""
    sweep = sweep_parse(spec, parse_time=_instant)
    bookable = {r.name: r for r in resources_bookable()}
    robot = bookable.get(sweep.robot)
    if robot is None or not robot.is_mobile:
        raise InvalidInput(
            f"robot: {sweep.robot!r} is not a robot that can be booked.",
            fields={"robot": [f"{sweep.robot!r} is not a robot that can be booked."]},
        )
    unknown = [n for n in sweep.nodes if n not in bookable]
    if unknown:
        raise InvalidInput(
            f"nodes: unknown: {', '.join(unknown)}", fields={"nodes": [f"Unknown: {unknown}"]}
        )
    _refuse_velocities(sweep, robot)
    nodes = [bookable[n] for n in sweep.nodes]
    runs = sweep.runs()
    with transaction.atomic():
        campaign = Campaign.objects.create(owner=owner, title=sweep.title, robot=robot, spec=spec)
        for index, run in enumerate(runs, start=1):
            label = (
                f"{sweep.title} #{index}: {run.velocity_mps:g} m/s {run.direction} "
                f"{run.duration_s:g} s, repeat {run.repeat}"
            )
            experiment = experiment_create(owner=owner, title=label[:200], segments=run.segments)
            queue_request_submit(
                owner=owner,
                experiment=experiment,
                robot=robot,
                nodes=nodes,
                earliest_at=sweep.earliest_at,
                latest_end_at=sweep.latest_end_at,
                hours_from=sweep.hours[0] if sweep.hours else None,
                hours_to=sweep.hours[1] if sweep.hours else None,
                title=label[:200],
                ip=ip,
                campaign=campaign,
                parameters=run.parameters,
            )
        audit_record(actor=owner, action="campaign.create", target=campaign, ip=ip, runs=len(runs))
    return campaign


def _refuse_velocities(sweep: Sweep, robot: Any) -> None:
    for velocity_mps in sweep.velocities_mps:
        why = velocity_problem(resource=robot, velocity_mps=velocity_mps)
        if why is not None:
            raise InvalidInput(f"velocity_mps: {why}", fields={"velocity_mps": [why]})


def _may_change(campaign: Campaign, by: User) -> None:
    if campaign.owner_id != by.pk and not by.is_testbed_admin:
        raise NotAllowed("Only the campaign's owner or an admin changes it.")


def campaign_pause(*, campaign: Campaign, by: User, ip: str | None = None) -> Campaign:
    """Hold the campaign's waiting runs back: the queue passes over them until resumed."""
    return _campaign_state(campaign, by, CampaignState.PAUSED, ip)


def campaign_resume(*, campaign: Campaign, by: User, ip: str | None = None) -> Campaign:
    return _campaign_state(campaign, by, CampaignState.ACTIVE, ip)


def _campaign_state(campaign: Campaign, by: User, state: CampaignState, ip: str | None) -> Campaign:
    _may_change(campaign, by)
    with transaction.atomic():
        locked = Campaign.objects.select_for_update().get(pk=campaign.pk)
        if locked.state == CampaignState.CANCELLED:
            raise Conflict("The campaign is cancelled.")
        locked.state = state
        locked.save(update_fields=["state", "updated_at"])
        audit_record(actor=by, action=f"campaign.{state.value}", target=locked, ip=ip)
        if state == CampaignState.ACTIVE:
            allocator_wake()
    return locked


def campaign_cancel(
    *, campaign: Campaign, by: User, cancel_booked: bool, reason: str = "", ip: str | None = None
) -> Campaign:
    """Withdraw the campaign's waiting runs; its booked runs are kept, or cancelled with their
    bookings when ``cancel_booked`` (those already ended are kept whatever is asked)."""
    _may_change(campaign, by)
    why = reason or f"campaign cancelled by {by.get_username()}"
    with transaction.atomic():
        locked = Campaign.objects.select_for_update().get(pk=campaign.pk)
        locked.state = CampaignState.CANCELLED
        locked.save(update_fields=["state", "updated_at"])
        for request in locked.requests.filter(state=RequestState.WAITING):
            queue_request_cancel(request=request, by=by, reason=why, ip=ip)
        if cancel_booked:
            booked = locked.requests.filter(
                state=RequestState.BOOKED, reservation__isnull=False
            ).select_related("reservation")
            for request in booked:
                reservation = request.reservation
                assert reservation is not None
                if reservation.state in ("requested", "confirmed"):
                    with_run.reservation_cancel(
                        reservation=reservation, by=by, reason=why, ip=ip, via=Channel.QUEUE
                    )
        audit_record(
            actor=by,
            action="campaign.cancel",
            target=locked,
            reason=reason,
            ip=ip,
            cancel_booked=cancel_booked,
        )
    return locked


def campaign_progress(campaign: Campaign) -> dict[str, Any]:
    """How far the campaign is: its runs by the queue's state and, once booked, by the run's."""
    requests = list(
        campaign.requests.select_related("reservation__run").order_by("submitted_at", "pk")
    )
    queue = Counter(r.state for r in requests)
    runs = Counter(
        r.reservation.run.state
        for r in requests
        if r.reservation is not None and hasattr(r.reservation, "run")
    )
    return {"runs": len(requests), "queue": dict(queue), "run_states": dict(runs)}


def campaign_requests(campaign: Campaign) -> list[QueueRequest]:
    return list(
        campaign.requests.select_related("reservation__run", "robot").order_by("submitted_at", "pk")
    )


def _settled(request: QueueRequest) -> str | None:
    """How a campaign's run ended (its run's end state, or the queue's), or None while it may
    still run."""
    if request.state in (RequestState.EXPIRED, RequestState.CANCELLED):
        return str(request.state)
    if request.state == RequestState.WAITING:
        return None
    run = getattr(request.reservation, "run", None) if request.reservation else None
    if run is not None:
        return str(run.state) if run.state in RUN_END_STATES else None
    if request.reservation is None or request.reservation.state not in ("requested", "confirmed"):
        return RunState.CANCELLED.value  # its booking gone or ended without a run
    return None


def campaign_done_check(campaign_id: int) -> bool:
    """Record ``campaign.done`` once every run of the campaign has settled; whether it was
    recorded now. Under the campaign's lock: two checks at once record it once."""
    with transaction.atomic():
        campaign = (
            Campaign.objects.select_for_update()
            .filter(pk=campaign_id, done_at__isnull=True)
            .select_related("robot")
            .first()
        )
        if campaign is None:
            return False
        ends = [_settled(r) for r in campaign_requests(campaign)]
        if not ends or None in ends:
            return False
        campaign.done_at = timezone.now()
        campaign.save(update_fields=["done_at", "updated_at"])
        counts = Counter(ends)
        event_record(
            subject=f"campaign:{campaign.pk}",
            type="campaign.done",
            owner_id=campaign.owner_id,
            payload={
                "campaign": campaign.pk,
                "title": campaign.title,
                "state": campaign.state,
                "robot": campaign.robot.name,
                "runs": len(ends),
                "ended": {str(k): v for k, v in sorted(counts.items())},
            },
        )
    return True
