"""``python -m basestation.sim.report`` prints the tables of docs/simulator.md."""

from __future__ import annotations

import pytest

from basestation.sim import report


def test_the_report_prints_stop_and_velocity_tables(capsys: pytest.CaptureFixture[str]) -> None:
    assert report.main(["--quick"]) == 0
    out = capsys.readouterr().out
    assert "## Stop distance against velocity" in out
    assert "## GPS-derived against robot-reported velocity" in out
    rows = [
        line for line in out.splitlines() if line.startswith("| 1.0 ") or line.startswith("| 2.0 ")
    ]
    assert len(rows) == 2
    assert "| NO |" not in out
