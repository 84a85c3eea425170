"""Answers kept in the cache until what they were computed from changes.

A ``Generation`` is a counter in the cache that names a family of answers (for example
everything the calendar shows). An answer is stored under the generation current when it was
computed; any change to the rows it depends on moves the generation on (after the change
commits), so the next read computes afresh and the old entries simply expire; the transaction
that made the change reads past the cache until it commits. An answer may
depend on several generations; a reader pays one cache round trip for all of them and the
answer together (each answer is kept beside the generations it was computed under, and used
only while they are all still current). Nothing is ever deleted by pattern.

Models declare what they feed through ``ChangeTrackedQuerySet`` and ``track_changes``: saves,
deletes, many-to-many changes, and the queryset's bulk writes (``update``, ``delete``,
``bulk_create``, ``bulk_update``) all move the generation on. Raw SQL does not: call
``Generation.changed`` after it.
"""

from __future__ import annotations

import functools
import hashlib
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any, TypeVar

from django.core.cache import cache
from django.db import connection, models, transaction
from django.db.models.signals import m2m_changed, post_delete, post_save

from core import sql

T = TypeVar("T")
_M = TypeVar("_M", bound=models.Model)

# An answer outlives its generation by at most this long in the cache (memory, not freshness:
# a changed generation is never read again).
ANSWER_TTL_S = 300


def database_namespace() -> str:
    """Which database a cache entry was computed from: ids repeat between databases (a
    test's, a benchmark's, a restore) that may share one cache."""
    db = connection.settings_dict
    where = f"{sql.database_kind()}:{db.get('HOST') or ''}:{db.get('PORT') or ''}:{db['NAME']}"
    return _namespace(where)


@functools.lru_cache(maxsize=64)
def _namespace(where: str) -> str:
    return hashlib.blake2b(where.encode(), digest_size=8).hexdigest()


class Generation:
    """A counter in the cache; answers computed under it are stale once it moves on."""

    def __init__(self, name: str) -> None:
        self.name = name

    def _key(self) -> str:
        return f"generation:{database_namespace()}:{self.name}"

    def current(self) -> int:
        key = self._key()
        value = cache.get(key)
        return int(value) if value is not None else self._start(key)

    @staticmethod
    def _start(key: str) -> int:
        # A new (or flushed) cache: start from the clock, never from a number an earlier
        # cache may have used for answers still held elsewhere.
        cache.add(key, time.time_ns(), timeout=None)
        value = cache.get(key)
        return int(value) if value is not None else time.time_ns()

    def changed(self) -> None:
        """Move on: now, or when the current transaction commits.

        Until the commit, other connections cannot see the change: what they compute meanwhile
        is stored under the generation of now, which the commit leaves behind. The
        transaction's own reads see its change, so they bypass the cache until then
        (``pending``). A transaction that writes several rows moves it once; one rolled back
        does not move it at all."""
        if connection.get_autocommit():
            self._bump()
        elif not self.pending():
            transaction.on_commit(self._bump)

    def pending(self) -> bool:
        """Whether the current transaction changed rows of this generation, not yet committed."""
        # Django keeps (savepoint ids, callback, robust) for each; those of a savepoint rolled
        # back are gone from it.
        return any(entry[1] == self._bump for entry in connection.run_on_commit)

    def _bump(self) -> None:
        key = self._key()
        incr_from = getattr(cache, "incr_from", None)
        if incr_from is not None:  # Redis: one round trip
            incr_from(key, time.time_ns())
            return
        try:
            cache.incr(key)
        except ValueError:  # not in the cache: the next reader starts a new one
            cache.add(key, time.time_ns(), timeout=None)

    def answer(self, parts: Iterable[object], compute: Callable[[], T]) -> T:
        """``compute()``, or what it gave under the current generation for the same ``parts``."""
        return cached_answer((self,), parts, compute)


def cached_answer(
    generations: Sequence[Generation], parts: Iterable[object], compute: Callable[[], T]
) -> T:
    """``compute()``, or what it gave for the same ``parts`` while every one of
    ``generations`` was what it is now.

    One round trip on a hit: the generations and the answer are read together. The answer
    is stored with the generations read before computing it, so an answer computed from rows
    that a change then replaced is never served once that change has moved its generation on.
    """
    if any(g.pending() for g in generations):
        return compute()  # this transaction's own changes: nobody else may see the answer yet
    namespace = database_namespace()
    generation_keys = [g._key() for g in generations]
    answer_key = (
        f"answer:{namespace}:{'+'.join(g.name for g in generations)}:"
        + hashlib.blake2b(repr(tuple(parts)).encode(), digest_size=12).hexdigest()
    )
    found = cache.get_many([*generation_keys, answer_key])
    current = tuple(
        int(found[key]) if key in found else Generation._start(key) for key in generation_keys
    )
    hit = found.get(answer_key)
    if isinstance(hit, tuple) and len(hit) == 2 and hit[0] == current:
        return hit[1]
    value = compute()
    cache.set(answer_key, (current, value), ANSWER_TTL_S)
    return value


class ChangeTrackedQuerySet(models.QuerySet[_M]):
    """A queryset whose bulk writes move its model's generations on (``track_changes``)."""

    def _changed(self) -> None:
        for generation in getattr(self.model, "_generations", ()):
            generation.changed()

    def update(self, **kwargs: Any) -> int:
        count = super().update(**kwargs)
        if count:
            self._changed()
        return count

    def delete(self) -> tuple[int, dict[str, int]]:
        result = super().delete()
        if result[0]:
            self._changed()
        return result

    def bulk_create(self, objs: Iterable[_M], *args: Any, **kwargs: Any) -> list[_M]:
        created = super().bulk_create(objs, *args, **kwargs)
        if created:
            self._changed()
        return created

    def bulk_update(self, objs: Iterable[_M], *args: Any, **kwargs: Any) -> int:
        count = super().bulk_update(objs, *args, **kwargs)
        if count:
            self._changed()
        return count


def track_changes(generation: Generation, *model_classes: type[models.Model]) -> None:
    """Every write to ``model_classes`` (and their many-to-many tables) moves ``generation``
    on. Each class's default manager must be built on ``ChangeTrackedQuerySet``."""

    def moved(**_: Any) -> None:
        generation.changed()

    for model in model_classes:
        manager = model._default_manager
        assert isinstance(manager.get_queryset(), ChangeTrackedQuerySet), (
            f"{model.__name__}'s manager must be built on ChangeTrackedQuerySet"
        )
        generations = model.__dict__.get("_generations", ())
        model._generations = (*generations, generation)  # type: ignore[attr-defined]
        uid = f"{generation.name}:{model._meta.label}"
        post_save.connect(moved, sender=model, weak=False, dispatch_uid=f"{uid}:save")
        post_delete.connect(moved, sender=model, weak=False, dispatch_uid=f"{uid}:delete")
        for field in model._meta.many_to_many:
            through = field.remote_field.through
            m2m_changed.connect(moved, sender=through, weak=False, dispatch_uid=f"{uid}:{field}")


def track_saves(generation: Generation, *senders: type[models.Model]) -> None:
    """Saves and deletes of ``senders``' rows move ``generation`` on, and so do additions and
    removals through a many-to-many table among them (``User.groups.through``). For models
    whose manager is not ours (Django's ``Group``, the user's groups): unlike
    ``track_changes``, a bulk write through their querysets goes unseen."""

    def moved(**_: Any) -> None:
        generation.changed()

    for sender in senders:
        uid = f"{generation.name}:{sender._meta.label}"
        if sender._meta.auto_created:  # a many-to-many table: written through its relation
            m2m_changed.connect(moved, sender=sender, weak=False, dispatch_uid=f"{uid}:m2m")
        else:
            post_save.connect(moved, sender=sender, weak=False, dispatch_uid=f"{uid}:save")
            post_delete.connect(moved, sender=sender, weak=False, dispatch_uid=f"{uid}:delete")
