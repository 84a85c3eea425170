"""The handlers of events, by name, with the types each wants (``core.events.dispatch``)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from core.events.catalogue import EVENT_TYPES
from core.events.models import Event

Handler = Callable[[Event], None]


@dataclass(frozen=True)
class Registration:
    name: str
    types: frozenset[str]
    fn: Handler
    # Whether it has anything to do now (the webhooks: some webhook exists); None: always.
    active: Callable[[], bool] | None = None
    # The Celery queue whose worker runs its passes; None: the events' own (the mail worker's).
    queue: str | None = None
    # New to a database, it starts after the events older than a few minutes, not at the
    # first (a live push of last year's events helps no one).
    from_end: bool = False


_HANDLERS: dict[str, Registration] = {}


def handler(
    name: str,
    *,
    types: Iterable[str],
    active: Callable[[], bool] | None = None,
    queue: str | None = None,
    from_end: bool = False,
) -> Callable[[Handler], Handler]:
    """Register ``fn`` as the handler ``name`` of ``types`` (each in the catalogue).

    ``active``, when given, says whether the handler has anything to do now: while it says
    no, its types wake no one and its cursor moves past what came (``events_dispatch``).
    ``queue`` names the worker that runs its passes when it must not wait behind the
    e-mails' (the live pushes: the runs worker); ``from_end`` starts it, on a database it is
    new to, after the events already there but the last few minutes'."""
    wanted = frozenset(types)
    unknown = sorted(wanted - set(EVENT_TYPES))
    if unknown or not wanted:
        raise ValueError(f"handler {name}: not event types: {unknown or 'none given'}")

    def register(fn: Handler) -> Handler:
        _HANDLERS[name] = Registration(name, wanted, fn, active, queue, from_end)
        return fn

    return register


def handlers() -> dict[str, Registration]:
    return dict(_HANDLERS)


def registration(name: str) -> Registration:
    return _HANDLERS[name]


def queues_wanting(type: str) -> set[str | None]:
    """The queues (``Registration.queue``) of the handlers that want events of ``type`` now."""
    return {
        registration.queue
        for registration in _HANDLERS.values()
        if type in registration.types and (registration.active is None or registration.active())
    }


def handled(type: str) -> bool:
    """Whether some handler wants events of ``type`` now."""
    return bool(queues_wanting(type))
