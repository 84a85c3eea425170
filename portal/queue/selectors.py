"""The queue as it stands: the fair-share order, each request's place and estimated start."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from datetime import datetime, timedelta

from django.conf import settings
from django.db.models import QuerySet

from bookings.choices import RESERVATION_ACTIVE_STATES, ReservationState, ResourceKind
from bookings.models import ReservationItem, Resource
from bookings.periods import overlap_s
from bookings.quotas import testbed_zone
from bookings.selectors import resource_free_intervals
from core.accounts.models import User
from portal.queue.models import Campaign, CampaignState, QueueControl, QueueRequest, RequestState
from portal.queue.slots import Period, allowed_periods, first_fit, intersection, without

# Robot time that counts as use: booked and not withdrawn (a completed booking was used).
USED_STATES = (*RESERVATION_ACTIVE_STATES, ReservationState.COMPLETED)


def queue_control() -> QueueControl:
    control, _ = QueueControl.objects.get_or_create(pk=1)
    return control


def queue_requests_visible(*, user: User) -> QuerySet[QueueRequest]:
    """The user's requests (every one for admins)."""
    qs = QueueRequest.objects.select_related("owner", "experiment", "robot", "reservation")
    qs = qs.prefetch_related("nodes")
    return qs if user.is_testbed_admin else qs.filter(owner=user)


def campaigns_visible(*, user: User) -> QuerySet[Campaign]:
    """The user's campaigns (every one for admins)."""
    qs = Campaign.objects.select_related("owner", "robot")
    return qs if user.is_testbed_admin else qs.filter(owner=user)


def fair_share_window(now: datetime) -> tuple[datetime, datetime]:
    """The period whose robot time counts as a person's use: the last
    ``QUEUE_FAIR_SHARE_WINDOW_S`` and what is booked up to the horizon (what the queue gave
    someone a moment ago counts against their next request)."""
    return (
        now - timedelta(seconds=settings.QUEUE_FAIR_SHARE_WINDOW_S),
        now + timedelta(seconds=settings.QUEUE_HORIZON_S),
    )


def robot_use_s(owner_ids: list[int], *, now: datetime) -> dict[int, float]:
    """Each owner's booked robot time (seconds) inside the fair-share window."""
    lo, hi = fair_share_window(now)
    used: dict[int, float] = defaultdict(float)
    items = ReservationItem.objects.filter(
        reservation__owner_id__in=owner_ids,
        reservation__state__in=USED_STATES,
        resource__kind=ResourceKind.MOBILE,
        start_at__lt=hi,
        end_at__gt=lo,
    ).values_list("reservation__owner_id", "start_at", "end_at")
    for owner_id, start_at, end_at in items:
        used[owner_id] += overlap_s(start_at, end_at, lo, hi)
    return {owner_id: used.get(owner_id, 0.0) for owner_id in owner_ids}


@dataclass(frozen=True)
class Waiting:
    request: QueueRequest
    use_s: float

    @property
    def order_key(self) -> tuple[int, float, datetime, int]:
        # An admin's priority first, then less recent use, then who asked first.
        return (-self.request.priority, self.use_s, self.request.submitted_at, self.request.pk)


def waiting_in_order(*, now: datetime) -> list[Waiting]:
    """The waiting requests in the order the queue serves them (the fair-share rule)."""
    requests = list(
        QueueRequest.objects.filter(state=RequestState.WAITING)
        .exclude(campaign__state=CampaignState.PAUSED)  # held back by its owner
        .select_related("owner", "experiment", "robot")
        .prefetch_related("nodes")
    )
    use = robot_use_s(sorted({r.owner_id for r in requests}), now=now)
    waiting = [Waiting(request, use[request.owner_id]) for request in requests]
    return sorted(waiting, key=lambda w: w.order_key)


def request_resources(request: QueueRequest) -> list[Resource]:
    return [request.robot, *sorted(request.nodes.all(), key=lambda r: r.pk)]


def request_search_period(request: QueueRequest, *, now: datetime) -> Period | None:
    """Where the request's booking may lie at all now: from its earliest start (not sooner
    than ``QUEUE_LEAD_S`` from now) to its latest end; None once that is too short."""
    lo = max(request.earliest_at, now + timedelta(seconds=settings.QUEUE_LEAD_S))
    hi = request.latest_end_at
    if hi - lo < timedelta(seconds=request.duration_s):
        return None
    return lo, hi


def request_free(
    request: QueueRequest, period: Period, *, taken: list[Period] | None = None
) -> list[Period]:
    """The parts of ``period`` in which all of the request's resources are free and its hours
    allow it, less ``taken`` (slots given to requests before it in a simulation)."""
    lo, hi = period
    free = allowed_periods(
        lo, hi, hours_from=request.hours_from, hours_to=request.hours_to, zone=testbed_zone()
    )
    for resource in request_resources(request):
        free = intersection(
            free, resource_free_intervals(resource=resource, start_at=lo, end_at=hi)
        )
    return without(free, taken or [])


def request_slot(
    request: QueueRequest, *, now: datetime, until: datetime | None = None
) -> Period | None:
    """The first slot the request fits in now, ending by ``until`` if given (the horizon)."""
    period = request_search_period(request, now=now)
    if period is None:
        return None
    if until is not None:
        period = (period[0], min(period[1], until))
        if period[0] >= period[1]:
            return None
    return first_fit(request_free(request, period), timedelta(seconds=request.duration_s))


@dataclass(frozen=True)
class Place:
    """A waiting request's place in the queue (1 is next) and where it would start if nothing
    changed: after the slots the requests before it would take (None: nowhere before its
    latest end)."""

    position: int
    estimated_start_at: datetime | None


def queue_places(*, now: datetime) -> dict[int, Place]:
    """Every waiting request's place, by its id: the allocator's pass simulated, the horizon
    aside (a request beyond it is booked once the horizon reaches its slot)."""
    places: dict[int, Place] = {}
    taken: dict[int, list[Period]] = defaultdict(list)  # by resource id
    for position, waiting in enumerate(waiting_in_order(now=now), start=1):
        request = waiting.request
        period = request_search_period(request, now=now)
        slot = None
        if period is not None:
            resources = request_resources(request)
            before = [p for r in resources for p in taken[r.pk]]
            slot = first_fit(
                request_free(request, period, taken=before),
                timedelta(seconds=request.duration_s),
            )
            if slot is not None:
                for resource in resources:
                    taken[resource.pk].append(slot)
        places[request.pk] = Place(position, slot[0] if slot is not None else None)
    return places
