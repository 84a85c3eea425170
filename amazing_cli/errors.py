"""What goes wrong, and the exit code each kind of problem gives (docs/cli.md)."""

from __future__ import annotations

OK = 0
# `watch`: the run ended, but not completed (failed, interrupted or cancelled).
RUN_NOT_COMPLETED = 1
BAD_INPUT = 2
REFUSED = 3
NOT_FOUND = 4
UNAVAILABLE = 5


class CliError(Exception):
    """A problem to report in one line, with the exit code it gives."""

    def __init__(
        self, message: str, *, exit_code: int, status: int | None = None, error: str | None = None
    ) -> None:
        super().__init__(message)
        self.message = message
        self.exit_code = exit_code
        # The portal's error code (``"error"`` of its envelope), e.g. ``mfa_required``.
        self.error = error
        # The portal's HTTP status, when it answered: a script tells a refusal (409) from a
        # request still in flight or a portal that is down, and retries only those.
        self.status = status


def bad_input(message: str) -> CliError:
    return CliError(message, exit_code=BAD_INPUT)
