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


_HANDLERS: dict[str, Registration] = {}


def handler(
    name: str, *, types: Iterable[str], active: Callable[[], bool] | None = None
) -> Callable[[Handler], Handler]:
    """Register ``fn`` as the handler ``name`` of ``types`` (each in the catalogue).

    ``active``, when given, says whether the handler has anything to do now: while it says
    no, its types wake no one and its cursor moves past what came (``events_dispatch``)."""
    wanted = frozenset(types)
    unknown = sorted(wanted - set(EVENT_TYPES))
    if unknown or not wanted:
        raise ValueError(f"handler {name}: not event types: {unknown or 'none given'}")

    def register(fn: Handler) -> Handler:
        _HANDLERS[name] = Registration(name, wanted, fn, active)
        return fn

    return register


def handlers() -> dict[str, Registration]:
    return dict(_HANDLERS)


def registration(name: str) -> Registration:
    return _HANDLERS[name]


def handled(type: str) -> bool:
    """Whether some handler wants events of ``type`` now."""
    return any(
        type in registration.types and (registration.active is None or registration.active())
        for registration in _HANDLERS.values()
    )
