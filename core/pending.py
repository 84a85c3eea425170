"""Tasks queued at most once at a time per subject: a run's staging, a queue's event pass.

The sweeps queue a task for every run still due on every pass (every second or two), and every
commit that records an event wakes its handlers' pass. When the worker falls behind (a busy
machine, a slow agent, a stuck mail server holding a lock) each pass would add a copy of what
is already waiting, the queue would grow faster than the worker empties it, and a task given
a short expiry to keep that pile small would expire before its turn: a run would never be
staged. Here a task is queued only if none for the same subject is waiting: a note in the
shared cache says one is (``cache.add``: atomic in Redis), and the task takes the note away as
it starts, so a change after that queues the next. A queued task that is lost (its worker
killed before it started) leaves a note that lapses after ``ttl_s``; the next pass queues it
again. The task expires after as long: by then a newer one is queued.

Celery itself keeps no such note; the small libraries that add one (``celery-once``,
``celery-singleton``) lock the run, not the wait, and are no longer released. This is
Django's cache and two calls.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from celery import Task
from django.core.cache import cache

from core.cache import database_namespace

logger = logging.getLogger(__name__)

# How long a note says a task is waiting, and how long the task waits before it expires.
# Longer than the worker's worst backlog on a busy machine (seconds), shorter than a run's
# stage lead: a lost task is queued again within this.
PENDING_TTL_S = 15.0


def _note(subject: str) -> str:
    # The database's namespace: tests and benches share one cache between databases.
    return f"pending:{database_namespace()}:{subject}"


def queue_once(
    task: Task,
    subject: str,
    *,
    args: Sequence[Any] = (),
    kwargs: dict[str, Any] | None = None,
    ttl_s: float = PENDING_TTL_S,
    **options: Any,
) -> bool:
    """Queue ``task`` unless one for ``subject`` is waiting; True if it was queued now.

    Without the cache (down) it queues anyway: a copy too many is harmless, a run never
    staged is not.
    """
    try:
        noted = bool(cache.add(_note(subject), 1, timeout=ttl_s))
    except Exception:
        logger.exception("the cache did not answer; %s (%s) queued regardless", task.name, subject)
        noted = True
    if not noted:
        return False
    try:
        task.apply_async(tuple(args), kwargs, expires=ttl_s, **options)
    except Exception:
        pending_taken(subject)  # nothing waits: the next pass queues it
        raise
    return True


def pending_taken(subject: str) -> None:
    """Called by the task as it starts: what changes from now on queues the next one."""
    try:
        cache.delete(_note(subject))
    except Exception:
        logger.exception("the cache did not answer; %s's note lapses by itself", subject)
