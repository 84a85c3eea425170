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

A model whose rows are read by many narrow answers (a week of one resource's bookings, one
user's quota) declares a ``Scope`` instead (``track_scoped_changes``): each written row moves
only the generations its values name, before and after the write, so a booking on one robot
in one week leaves every other week's and every other user's answers in the cache. A
transaction's generations move on together at its commit, in one round trip.
"""

from __future__ import annotations

import functools
import hashlib
import time
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Self, TypeVar

from django.core.cache import cache
from django.db import connection, models, transaction
from django.db.models.signals import m2m_changed, post_delete, post_save, pre_save

from core import sql
from core.commit_batch import CommitBatch

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
    """A counter in the cache; answers computed under it are stale once it moves on.

    Generations are named: two objects of the same name are the same counter (answers
    scoped to a week or a user make theirs as they need them)."""

    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Generation) and other.name == self.name

    def __hash__(self) -> int:
        return hash(self.name)

    def __repr__(self) -> str:
        return f"Generation({self.name!r})"

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
        """Move on: now, or when the current transaction commits (``changed_together``)."""
        changed_together((self,))

    def pending(self) -> bool:
        """Whether the current transaction changed rows of this generation, not yet committed."""
        return any(self.name in batch.names for batch in _Batch.waiting())

    def answer(self, parts: Iterable[object], compute: Callable[[], T]) -> T:
        """``compute()``, or what it gave under the current generation for the same ``parts``."""
        return cached_answer((self,), parts, compute)


class _Batch(CommitBatch):
    """The generations a transaction moves on at its commit, all in one round trip."""

    def __init__(self) -> None:
        super().__init__()
        self.names: set[str] = set()

    def run(self) -> None:
        _bump(self.names)


def changed_together(generations: Iterable[Generation]) -> None:
    """Move ``generations`` on: now, or when the current transaction commits.

    Until the commit, other connections cannot see the change: what they compute meanwhile
    is stored under the generations of now, which the commit leaves behind. The
    transaction's own reads see its change, so they bypass the cache until then
    (``Generation.pending``). A transaction that writes several rows moves each generation
    once; one rolled back moves nothing."""
    names = {g.name for g in generations}
    if not names:
        return
    if connection.get_autocommit():
        _bump(names)
        return
    _Batch.current().names |= names


def _bump(names: Collection[str]) -> None:
    namespace = database_namespace()
    keys = [f"generation:{namespace}:{name}" for name in sorted(names)]
    incr_many_from = getattr(cache, "incr_many_from", None)
    if incr_many_from is not None:  # Redis: one round trip for them all
        incr_many_from(keys, time.time_ns())
        return
    for key in keys:
        try:
            cache.incr(key)
        except ValueError:  # not in the cache: the next reader starts a new one
            cache.add(key, time.time_ns(), timeout=None)


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
    # The first generation's name for a person reading the cache; the digest for the rest (a
    # month of weeks would make a key longer than a cache should take).
    answer_key = (
        f"answer:{namespace}:{generations[0].name if generations else ''}:"
        + hashlib.blake2b(
            repr((tuple(g.name for g in generations), tuple(parts))).encode(), digest_size=12
        ).hexdigest()
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


@dataclass(frozen=True)
class Scope:
    """What a write to a model's rows moves on: ``generations_of(rows)``, given each written
    row's values of ``fields`` (attribute names, as ``values()`` names them) as they were
    before the write and as they are after it. ``everything`` is what a write moves when its
    rows are not known (a many-to-many table cleared from the other side)."""

    fields: tuple[str, ...]
    generations_of: Callable[[Sequence[Mapping[str, Any]]], Iterable[Generation]]
    everything: tuple[Generation, ...]


def _scope(model: type[models.Model]) -> Scope | None:
    return getattr(model, "_cache_scope", None)


def _row(instance: models.Model, scope: Scope) -> dict[str, Any]:
    return {name: getattr(instance, name) for name in scope.fields}


class ScopeTracked:
    """Mixed into a model whose rows remember the values their scope was loaded with, so that
    a save moves on the generations of where the row was as well as of where it is now."""

    @classmethod
    def from_db(cls, db: str | None, field_names: Collection[str], values: Collection[Any]) -> Self:
        instance = super().from_db(db, field_names, values)  # type: ignore[misc]
        scope = getattr(cls, "_cache_scope", None)
        if scope is not None:
            loaded = dict(zip(field_names, values, strict=True))
            if all(name in loaded for name in scope.fields):
                instance._scope_loaded = {name: loaded[name] for name in scope.fields}
        return instance


class ChangeTrackedQuerySet(models.QuerySet[_M]):
    """A queryset whose bulk writes move its model's generations on (``track_changes``), or,
    for a model with a ``Scope``, those of the rows it wrote (``track_scoped_changes``)."""

    def _changed(self) -> None:
        changed_together(self._generations())

    def _rows(self, pks: Iterable[Any], scope: Scope) -> list[dict[str, Any]]:
        return list(self.model._base_manager.filter(pk__in=list(pks)).values(*scope.fields))

    def update(self, **kwargs: Any) -> int:
        scope = _scope(self.model)
        if scope is None:
            count = super().update(**kwargs)
            if count:
                self._changed()
            return count
        # The rows are locked as they are read, so the values read before are those the
        # update replaces, and it writes exactly those rows.
        with transaction.atomic(using=self.db):
            before = list(self.select_for_update(of=("self",)).values("pk", *scope.fields))
            if not before:
                return 0
            pks = [row.pop("pk") for row in before]
            count = super(ChangeTrackedQuerySet, self.filter(pk__in=pks)).update(**kwargs)
            written = {
                getattr(self.model._meta.get_field(name), "attname", name) for name in kwargs
            }
            after = self._rows(pks, scope) if written & set(scope.fields) else []
            changed_together([*scope.generations_of([*before, *after]), *self._generations()])
        return count

    def _generations(self) -> tuple[Generation, ...]:
        return tuple(getattr(self.model, "_generations", ()))

    def delete(self) -> tuple[int, dict[str, int]]:
        result = super().delete()
        # A scoped model's rows are each deleted with its signal, which moves their scope.
        if result[0] and _scope(self.model) is None:
            self._changed()
        return result

    def bulk_create(self, objs: Iterable[_M], *args: Any, **kwargs: Any) -> list[_M]:
        created = super().bulk_create(objs, *args, **kwargs)
        if created:
            scope = _scope(self.model)
            if scope is None:
                self._changed()
            else:
                rows = [_row(obj, scope) for obj in created]
                changed_together([*scope.generations_of(rows), *self._generations()])
                for obj, row in zip(created, rows, strict=True):
                    obj._scope_loaded = row  # type: ignore[attr-defined]
        return created

    def bulk_update(self, objs: Iterable[_M], *args: Any, **kwargs: Any) -> int:
        scope = _scope(self.model)
        if scope is None:
            count = super().bulk_update(objs, *args, **kwargs)
            if count:
                self._changed()
            return count
        objs = list(objs)
        with transaction.atomic(using=self.db):
            pks = [obj.pk for obj in objs]
            before = list(
                self.model._base_manager.filter(pk__in=pks)
                .select_for_update(of=("self",))
                .values(*scope.fields)
            )
            count = super().bulk_update(objs, *args, **kwargs)
            rows = [_row(obj, scope) for obj in objs]
            changed_together([*scope.generations_of([*before, *rows]), *self._generations()])
        for obj, row in zip(objs, rows, strict=True):
            obj._scope_loaded = row  # type: ignore[attr-defined]
        return count


def track_scoped_changes(model: type[models.Model], scope: Scope) -> None:
    """Every write to ``model``'s rows moves on the generations ``scope`` names for the rows
    written, as they were and as they are (saves, deletes, the queryset's bulk writes, and
    many-to-many changes). Its default manager must be built on ``ChangeTrackedQuerySet``."""
    manager = model._default_manager
    assert isinstance(manager.get_queryset(), ChangeTrackedQuerySet), (
        f"{model.__name__}'s manager must be built on ChangeTrackedQuerySet"
    )
    assert _scope(model) is None, f"{model.__name__} has a scope already"
    model._cache_scope = scope  # type: ignore[attr-defined]

    def before_save(instance: models.Model, **_: Any) -> None:
        if not instance._state.adding and not hasattr(instance, "_scope_loaded") and instance.pk:
            # Loaded without its scope's fields (``only``) or made by hand: read where it was.
            found = ChangeTrackedQuerySet(model)._rows([instance.pk], scope)
            if found:
                instance._scope_loaded = found[0]  # type: ignore[attr-defined]

    def saved(instance: models.Model, **_: Any) -> None:
        now = _row(instance, scope)
        before = getattr(instance, "_scope_loaded", None)
        changed_together(scope.generations_of([now] if before is None else [before, now]))
        instance._scope_loaded = now  # type: ignore[attr-defined]

    def deleted(instance: models.Model, **_: Any) -> None:
        row = getattr(instance, "_scope_loaded", None) or _row(instance, scope)
        changed_together(scope.generations_of([row]))

    def related(instance: models.Model, action: str, pk_set: set[Any] | None, **_: Any) -> None:
        if not action.startswith("post_"):
            return
        if isinstance(instance, model):
            changed_together(scope.generations_of([_row(instance, scope)]))
        elif pk_set:
            changed_together(
                scope.generations_of(ChangeTrackedQuerySet(model)._rows(pk_set, scope))
            )
        else:
            changed_together(scope.everything)

    uid = f"scope:{model._meta.label}"
    pre_save.connect(before_save, sender=model, weak=False, dispatch_uid=f"{uid}:before")
    post_save.connect(saved, sender=model, weak=False, dispatch_uid=f"{uid}:save")
    post_delete.connect(deleted, sender=model, weak=False, dispatch_uid=f"{uid}:delete")
    for field in model._meta.many_to_many:
        through = field.remote_field.through
        m2m_changed.connect(related, sender=through, weak=False, dispatch_uid=f"{uid}:{field}")


def track_changes(
    generations: Generation | Sequence[Generation], *model_classes: type[models.Model]
) -> None:
    """Every write to ``model_classes`` (and their many-to-many tables) moves ``generations``
    on. Each class's default manager must be built on ``ChangeTrackedQuerySet``."""
    moves = _generations(generations)
    name = "+".join(g.name for g in moves)

    def moved(**_: Any) -> None:
        changed_together(moves)

    for model in model_classes:
        manager = model._default_manager
        assert isinstance(manager.get_queryset(), ChangeTrackedQuerySet), (
            f"{model.__name__}'s manager must be built on ChangeTrackedQuerySet"
        )
        tracked = model.__dict__.get("_generations", ())
        model._generations = (*tracked, *moves)  # type: ignore[attr-defined]
        uid = f"{name}:{model._meta.label}"
        post_save.connect(moved, sender=model, weak=False, dispatch_uid=f"{uid}:save")
        post_delete.connect(moved, sender=model, weak=False, dispatch_uid=f"{uid}:delete")
        for field in model._meta.many_to_many:
            through = field.remote_field.through
            m2m_changed.connect(moved, sender=through, weak=False, dispatch_uid=f"{uid}:{field}")


def _generations(generations: Generation | Sequence[Generation]) -> tuple[Generation, ...]:
    return (generations,) if isinstance(generations, Generation) else tuple(generations)


def track_saves(
    generations: Generation | Sequence[Generation], *senders: type[models.Model]
) -> None:
    """Saves and deletes of ``senders``' rows move ``generations`` on, and so do additions and
    removals through a many-to-many table among them (``User.groups.through``). For models
    whose manager is not ours (Django's ``Group``, the user's groups): unlike
    ``track_changes``, a bulk write through their querysets goes unseen."""

    moves = _generations(generations)
    name = "+".join(g.name for g in moves)

    def moved(**_: Any) -> None:
        changed_together(moves)

    for sender in senders:
        uid = f"{name}:{sender._meta.label}"
        if sender._meta.auto_created:  # a many-to-many table: written through its relation
            m2m_changed.connect(moved, sender=sender, weak=False, dispatch_uid=f"{uid}:m2m")
        else:
            post_save.connect(moved, sender=sender, weak=False, dispatch_uid=f"{uid}:save")
            post_delete.connect(moved, sender=sender, weak=False, dispatch_uid=f"{uid}:delete")
