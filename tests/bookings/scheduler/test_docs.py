"""docs/integration.md keeps up with the code: every setting, every switch, every section."""

from __future__ import annotations

import re
from pathlib import Path

from bookings.scheduler.config import ENV_NAMES
from bookings.scheduler.standin import ENV_PREFIX, build_parser

DOC = Path(__file__).resolve().parents[3] / "docs" / "integration.md"


def test_it_documents_every_scheduler_setting() -> None:
    text = DOC.read_text()
    missing = [name for name in ENV_NAMES if f"`{name}`" not in text]
    assert not missing


def test_it_documents_every_switch_of_the_stand_in() -> None:
    text = DOC.read_text()
    flags = set(re.findall(r"--[a-z0-9][a-z0-9-]+", build_parser().format_help()))
    flags -= {"--help", "--no-empty-as-404", "--no-test-control"}
    assert {"--conflict-as", "--granularity-s", "--test-control", "--db"} <= flags
    assert not [flag for flag in sorted(flags) if flag not in text]
    source = (DOC.parents[1] / "bookings" / "scheduler" / "standin" / "config.py").read_text()
    variables = {ENV_PREFIX + name for name in re.findall(r'get\("([A-Z0-9_]+)"\)', source)}
    assert len(variables) >= 7
    assert not [name for name in sorted(variables) if name not in text and name[:-5] not in text]


def test_it_keeps_the_sections_the_booking_integration_fills_in() -> None:
    headings = re.findall(r"^## (.+)$", DOC.read_text(), flags=re.MULTILINE)
    for section in ("Booking flow", "Mirror", "Inbound", "Admin and health"):
        assert section in headings
