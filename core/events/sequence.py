"""Numbering committed events: their position (one order, the order of the commits) and their
subject's seq (see the package's docstring)."""

from __future__ import annotations

from django.db import transaction
from django.db.models import Max

from core import sql
from core.events.models import Event

SEQUENCER_LOCK_KEY = sql.advisory_key(b"eventseq")
# Rows numbered per pass: a backlog (after a crash) is worked through in passes this size.
SEQUENCE_BATCH = 500


def events_sequence() -> int:
    """Number every committed event not numbered yet, in the order they were written; how
    many were numbered.

    One sequencer at a time (an advisory lock): each pass sees the rows committed before it
    took the lock and numbers them after every number given before, so a number is never
    given to a row a reader could have skipped. Rows of one subject are written under that
    subject's row lock (the reservation's, the run's), one transaction after the other, so
    their ids, and with them their ``seq``, follow the order of the changes.
    """
    numbered = 0
    while True:
        with transaction.atomic():
            sql.advisory_xact_lock(SEQUENCER_LOCK_KEY)
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
