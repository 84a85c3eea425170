"""The suite's own settings: what every test inherits."""

from __future__ import annotations

from hypothesis import settings


def test_no_property_test_has_a_deadline() -> None:
    # A loaded machine makes an example slow, not wrong: tests/conftest.py loads the profile.
    assert settings.default.deadline is None
