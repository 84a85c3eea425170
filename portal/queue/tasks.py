from __future__ import annotations

from typing import Any

from celery import shared_task

from core.pending import pending_taken
from portal.queue.allocation import queue_allocate

# One pass waits at a time (core.pending): a campaign's requests and a resume wake it once.
ALLOCATE_SUBJECT = "queue-allocate"


@shared_task
def queue_allocate_task() -> dict[str, Any]:
    """One pass of the queue's allocator (woken by a request, a resume, a reorder or a freed
    slot; beat's pass books what the moving horizon reaches)."""
    pending_taken(ALLOCATE_SUBJECT)
    done = queue_allocate()
    return {
        "booked": done.booked,
        "expired": done.expired,
        "waiting": done.waiting,
        "paused": done.paused,
    }
