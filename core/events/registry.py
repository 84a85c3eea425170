"""The handlers of events, by name, with the types each wants (``core.events.dispatch``)."""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable
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


def queues_wanting(
    type: str, *, woken: Collection[str | None] = (), inactive: set[str] | None = None
) -> set[str | None]:
    """The queues (``Registration.queue``) of the handlers that want events of ``type`` now.

    Asking a handler whether it is active may be a query (the webhooks': does any webhook
    exist?), and a booking records several events. So a handler whose queue is in ``woken``
    (already to be woken) is not asked, nor one named in ``inactive`` (found inactive earlier
    in the transaction); those found inactive now are added to ``inactive``. A handler that
    becomes active later in that transaction is passed its events by beat's pass."""
    wanting: set[str | None] = set()
    for name, registration in _HANDLERS.items():
        if type not in registration.types or registration.queue in woken:
            continue
        if registration.active is not None:
            if inactive is not None and name in inactive:
                continue
            if not registration.active():
                if inactive is not None:
                    inactive.add(name)
                continue
        wanting.add(registration.queue)
    return wanting


def handled(type: str) -> bool:
    """Whether some handler wants events of ``type`` now."""
    return bool(queues_wanting(type))
