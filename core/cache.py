"""Answers kept in the cache until what they were computed from changes.

A ``Generation`` is a counter in the cache that names a family of answers (for example
everything the calendar shows). An answer is stored under the generation current when it was
computed; any change to the rows it depends on moves the generation on (after the change
commits), so the next read computes afresh and the old entries simply expire. Readers pay one
cache round trip for the generation and one for the answer; nothing is ever deleted by pattern.

Models declare what they feed through ``ChangeTrackedQuerySet`` and ``track_changes``: saves,
deletes, many-to-many changes, and the queryset's bulk writes (``update``, ``delete``,
``bulk_create``, ``bulk_update``) all move the generation on. Raw SQL does not: call
``Generation.changed`` after it.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

from django.core.cache import cache
from django.db import connection, models, transaction
from django.db.models.signals import m2m_changed, post_delete, post_save

T = TypeVar("T")
_M = TypeVar("_M", bound=models.Model)

# An answer outlives its generation by at most this long in the cache (memory, not freshness:
# a changed generation is never read again).
ANSWER_TTL_S = 300


def database_namespace() -> str:
    """Which database a cache entry was computed from: ids repeat between databases (a
    test's, a benchmark's, a restore) that may share one cache."""
    db = connection.settings_dict
    where = f"{connection.vendor}:{db.get('HOST') or ''}:{db.get('PORT') or ''}:{db['NAME']}"
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
        if value is None:
            # A new (or flushed) cache: start from the clock, never from a number an earlier
            # cache may have used for answers still held elsewhere.
            cache.add(key, time.time_ns(), timeout=None)
            value = cache.get(key)
        return int(value) if value is not None else time.time_ns()

    def changed(self) -> None:
        """Move on now and, inside a transaction, once more when it commits: a reader in
        between computes from the rows before the change and stores that under the
        generation of now, which the second step leaves behind."""
        self._bump()
        if not connection.get_autocommit():
            transaction.on_commit(self._bump)

    def _bump(self) -> None:
        key = self._key()
        try:
            cache.incr(key)
        except ValueError:  # not in the cache: the next reader starts a new one
            cache.add(key, time.time_ns(), timeout=None)

    def answer(self, parts: Iterable[object], compute: Callable[[], T]) -> T:
        """``compute()``, or what it gave under the current generation for the same ``parts``."""
        generation = self.current()
        key = (
            f"answer:{database_namespace()}:{self.name}:{generation}:"
            + hashlib.blake2b(repr(tuple(parts)).encode(), digest_size=12).hexdigest()
        )
        hit = cache.get(key)
        if hit is not None:
            return hit
        value = compute()
        cache.set(key, value, ANSWER_TTL_S)
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
