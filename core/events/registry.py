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


_HANDLERS: dict[str, Registration] = {}


def handler(name: str, *, types: Iterable[str]) -> Callable[[Handler], Handler]:
    """Register ``fn`` as the handler ``name`` of ``types`` (each in the catalogue)."""
    wanted = frozenset(types)
    unknown = sorted(wanted - set(EVENT_TYPES))
    if unknown or not wanted:
        raise ValueError(f"handler {name}: not event types: {unknown or 'none given'}")

    def register(fn: Handler) -> Handler:
        _HANDLERS[name] = Registration(name, wanted, fn)
        return fn

    return register


def handlers() -> dict[str, Registration]:
    return dict(_HANDLERS)


def registration(name: str) -> Registration:
    return _HANDLERS[name]


def handled(type: str) -> bool:
    """Whether some handler wants events of ``type``."""
    return any(type in registration.types for registration in _HANDLERS.values())
