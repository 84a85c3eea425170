"""The queue's reactions to events (``core.events.dispatch``): a slot freed or moved may let a
waiting request in at once, not only at beat's next pass. Imported when the app is ready."""

from __future__ import annotations

from core.events.dispatch import handler
from core.events.models import Event
from portal.queue.allocation import queue_allocate
from portal.queue.campaigns import campaign_done_check
from portal.queue.models import Campaign, QueueRequest, RequestState


def _anyone_waiting() -> bool:
    return QueueRequest.objects.filter(state=RequestState.WAITING).exists()


@handler(
    "queue-allocate",
    types=["reservation.cancelled", "reservation.moved", "reservation.rejected"],
    active=_anyone_waiting,
    from_end=True,
)
def queue_on_calendar_change(event: Event) -> None:
    queue_allocate()


def _campaigns_open() -> bool:
    return Campaign.objects.filter(done_at__isnull=True).exists()


@handler(
    "campaign-done",
    types=[
        "run.completed",
        "run.failed",
        "run.interrupted",
        "run.cancelled",
        "queue.expired",
        "queue.cancelled",
    ],
    active=_campaigns_open,
)
def campaign_on_run_end(event: Event) -> None:
    """A run or a request of a campaign ended: the campaign may be done."""
    payload = event.payload
    requests = QueueRequest.objects.filter(campaign__isnull=False)
    if "request" in payload:
        requests = requests.filter(pk=payload["request"])
    else:
        requests = requests.filter(reservation_id=payload["reservation"])
    for campaign_id in requests.values_list("campaign_id", flat=True):
        assert campaign_id is not None
        campaign_done_check(campaign_id)
