"""Domain errors raised by services; ``core.api.exception_handler`` maps them to HTTP."""

from __future__ import annotations


class DomainError(Exception):
    """A request the domain refuses. ``fields`` maps a field name to its messages."""

    http_status = 400
    code = "invalid"

    def __init__(self, message: str, *, fields: dict[str, list[str]] | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.fields = fields or {}

    @classmethod
    def on_field(cls, field: str, message: str) -> DomainError:
        return cls(message, fields={field: [message]})


class InvalidInput(DomainError):
    http_status = 400
    code = "invalid"


class Conflict(DomainError):
    http_status = 409
    code = "conflict"


class NotAllowed(DomainError):
    http_status = 403
    code = "forbidden"


class Busy(DomainError):
    """Too much at once from one client (downloads in flight): 429, try again after
    ``retry_after_s`` (the ``Retry-After`` header)."""

    http_status = 429
    code = "throttled"

    def __init__(self, message: str, *, retry_after_s: int) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s
