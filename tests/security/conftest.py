"""Fixtures of the door attacks: the real agent behind the portal (tests/runs)."""

from tests.runs.conftest import agent  # noqa: F401
