"""How long each test file takes, so that the workers are handed the longest files first.

``tests/durations.json`` maps each test file to its seconds in a whole run of the suite; the
suite's ordering (``tests/conftest.py``) reads it. Refresh it from a run's JUnit report:

    python -m pytest --junitxml=var/suite.xml
    python -m tests.durations var/suite.xml

A file missing from it (a new one) is placed by its markers: ``long`` with the longest,
``integration``/``browser`` before the unit tests.
"""

from __future__ import annotations

import json
import sys
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

DURATIONS = Path(__file__).with_name("durations.json")
# Seconds assumed for a file not in the table, by its markers.
UNKNOWN_LONG_S = 120.0
UNKNOWN_SLOW_S = 20.0
UNKNOWN_S = 1.0


def file_durations() -> dict[str, float]:
    """The table, or nothing when it is missing or unreadable (the markers then decide)."""
    try:
        table = json.loads(DURATIONS.read_text())
    except (OSError, ValueError):
        return {}
    return {str(k): float(v) for k, v in table.items()} if isinstance(table, dict) else {}


def from_junit(report: Path) -> dict[str, float]:
    """Seconds per test file (its tests' total) in a pytest JUnit report."""
    seconds: Counter[str] = Counter()
    for case in ET.parse(report).iter("testcase"):  # noqa: S314 (a report this suite wrote)
        module = case.get("classname", "")
        seconds[module.replace(".", "/") + ".py"] += float(case.get("time") or 0)
    return {name: round(total, 1) for name, total in sorted(seconds.items())}


def main(argv: list[str]) -> None:
    if len(argv) != 1:
        raise SystemExit("usage: python -m tests.durations JUNIT_XML")
    DURATIONS.write_text(json.dumps(from_junit(Path(argv[0])), indent=1) + "\n")
    print(f"written {DURATIONS}")


if __name__ == "__main__":
    main(sys.argv[1:])
