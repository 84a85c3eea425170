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
    def waiting(cls) -> list[Self]:
        """The current transaction's batches of this kind that have not run yet."""
        found = (entry[1] for entry in connection.run_on_commit)
        return [c for c in found if isinstance(c, cls) and not c.ran]

    @classmethod
    def current(cls) -> Self:
        """The batch of this kind to add to now: the current transaction's, begun now if need
        be."""
        batch = cls.joinable()
        if batch is None:
            batch = cls()
            transaction.on_commit(batch)
        return batch

    @classmethod
    def joinable(cls) -> Self | None:
        """The batch of this kind to add to now, if the current transaction has begun one."""
        # Django keeps (savepoint ids, callback, robust) for each on-commit callback and drops
        # those of a savepoint rolled back, a batch begun there included: the next change
        # begins another. What an outer batch took from a savepoint later rolled back does
        # one thing too many at the commit, never one too few. Never joined once it ran: a
        # test's transaction never commits, and runs the callbacks of one block at a time.
        #
        # Joined from the block it was begun in, from blocks nested in that one, and from the
        # block that encloses a savepoint released since (the booking's reservation is written
        # in a block of its own, its run after it: one batch, not two). Not joined from a
        # block beside the one it was begun in: in a test those are earlier "transactions"
        # (the fixtures', say) inside the test's own, whose callbacks run only when captured.
        active = connection.savepoint_ids
        innermost = next((sid for sid in reversed(active) if sid is not None), None)
        for entry in connection.run_on_commit:
            sids, callback = set(entry[0]), entry[1]
            if not isinstance(callback, cls) or callback.ran:
                continue
            if sids <= set(active) or innermost is None or innermost in sids:
                return callback
        return None
