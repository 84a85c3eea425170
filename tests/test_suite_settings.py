"""The suite's own settings: what every test inherits."""

from __future__ import annotations

import psycopg
import pytest
from django.db import OperationalError
from hypothesis import settings

from tests.conftest import FLUSH_TRIES, flush_tried_again


def test_no_property_test_has_a_deadline() -> None:
    # A loaded machine makes an example slow, not wrong: tests/conftest.py loads the profile.
    assert settings.default.deadline is None


def _deadlock() -> OperationalError:
    error = OperationalError("deadlock detected")
    error.__cause__ = psycopg.errors.DeadlockDetected("deadlock detected")
    return error


def test_a_flush_aborted_by_a_deadlock_is_tried_again_and_other_errors_are_not() -> None:
    tries: list[list[str]] = []

    def flush(self: object, sql_list: list[str]) -> None:
        tries.append(sql_list)
        if len(tries) < 3:
            raise _deadlock()

    flush_tried_again(flush)(None, ["TRUNCATE a, b"])
    assert len(tries) == 3

    def always(self: object, sql_list: list[str]) -> None:
        tries.append(sql_list)
        raise _deadlock()

    tries.clear()
    with pytest.raises(OperationalError):
        flush_tried_again(always)(None, ["TRUNCATE a"])
    assert len(tries) == FLUSH_TRIES

    def broken(self: object, sql_list: list[str]) -> None:
        tries.append(sql_list)
        raise OperationalError("server closed the connection")

    tries.clear()
    with pytest.raises(OperationalError, match="server closed"):
        flush_tried_again(broken)(None, ["TRUNCATE a"])
    assert len(tries) == 1
