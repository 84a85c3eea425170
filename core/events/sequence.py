"""Numbering committed events: their position (one order, the order of the commits) and their
subject's seq (see the package's docstring)."""

from __future__ import annotations

import logging

from django.db import transaction
from django.db.models import Max

from core import sql
from core.events.models import Event

logger = logging.getLogger(__name__)

SEQUENCER_LOCK_KEY = sql.advisory_key(b"eventseq")
# Rows numbered per pass: a backlog (after a crash) is worked through in passes this size.
SEQUENCE_BATCH = 500
# The longest a caller waits for the sequencer's lock. A pass holds it for milliseconds; a
# process frozen inside one (stopped, paused, swapped out) holds it until it moves again, and
# every caller waiting on it would wait as long: the runs worker's threads all did, and no
# run was staged. A caller that gives up numbers nothing now; the holder, or the next
# caller, numbers what it left.
SEQUENCER_WAIT_S = 2.0


def events_sequence() -> int:
    """Number every committed event not numbered yet, in the order they were written; how
    many were numbered.

    One sequencer at a time (an advisory lock): each pass sees the rows committed before it
    took the lock and numbers them after every number given before, so a number is never
    given to a row a reader could have skipped. Rows of one subject are written under that
    subject's row lock (the reservation's, the run's), one transaction after the other, so
    their ids, and with them their ``seq``, follow the order of the changes. A caller that
    cannot take the lock within ``SEQUENCER_WAIT_S`` returns what it numbered so far.
    """
    numbered = 0
    while True:
        with transaction.atomic():
            if not sql.advisory_xact_lock_within(SEQUENCER_LOCK_KEY, SEQUENCER_WAIT_S):
                logger.warning(
                    "events not numbered: another sequencer has held the lock for %.0f s",
                    SEQUENCER_WAIT_S,
                )
                return numbered
            pending = list(
                Event.objects.filter(position__isnull=True)
                .order_by("id")
                .only("id", "subject")[:SEQUENCE_BATCH]
            )
            if not pending:
                return numbered
            top = Event.objects.aggregate(top=Max("position"))["top"] or 0
            subjects = {e.subject for e in pending}
            seqs: dict[str, int] = dict(
                Event.objects.filter(subject__in=subjects, seq__isnull=False)
                .values("subject")
                .annotate(top=Max("seq"))
                .values_list("subject", "top")
            )
            for event in pending:
                top += 1
                seqs[event.subject] = seqs.get(event.subject, 0) + 1
                event.position = top
                event.seq = seqs[event.subject]
            Event.objects.bulk_update(pending, ["position", "seq"])
            numbered += len(pending)
        if len(pending) < SEQUENCE_BATCH:
            return numbered
