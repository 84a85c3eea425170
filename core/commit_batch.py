"""Work a transaction gathers as it goes and does once, at its commit.

A booking writes several rows and records several events; what follows from each (a cached
answer's generation moved on, the event handlers woken) is the same for all of them, so it is
gathered in one on-commit callback per transaction instead of one per row or event.
"""

from __future__ import annotations

from typing import Self

from django.db import connection, transaction


class CommitBatch:
    """One per transaction and subclass: ``current()`` finds the pending one or registers a
    new one; ``run`` is called once, after the commit (never, if the transaction rolls back).
    Outside a transaction there is nothing to wait for: the caller acts at once."""

    def __init__(self) -> None:
        self.ran = False

    def __call__(self) -> None:
        self.ran = True
        self.run()

    def run(self) -> None:
        raise NotImplementedError

    @classmethod
    def pending(cls) -> Self | None:
        """The current transaction's batch of this kind, if it has begun one."""
        # Django keeps (savepoint ids, callback, robust) for each on-commit callback; those of
        # a savepoint rolled back are gone from it, and so is a batch begun there: the next
        # change begins another. What was added from a savepoint later rolled back stays in an
        # outer batch, which then does one thing too many at the commit, never one too few.
        # A batch that ran is never reused (tests run callbacks inside a transaction that
        # never commits, so the list keeps them).
        for entry in connection.run_on_commit:
            if isinstance(entry[1], cls) and not entry[1].ran:
                return entry[1]
        return None

    @classmethod
    def current(cls) -> Self:
        """The current transaction's batch of this kind, begun now if need be."""
        batch = cls.pending()
        if batch is None:
            batch = cls()
            transaction.on_commit(batch)
        return batch
