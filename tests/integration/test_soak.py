"""The soak (``make soak``) in short: the whole system on a private PostgreSQL cluster and
Redis, two robots booked back to back (some with a fixed node) while a fault is injected every
12 to 20 s, until each kind — the runs worker, the mail worker, beat, Redis, an agent, the web
server, the stand-in scheduler killed, and PostgreSQL restarted — has occurred once and runs
went on through one more pause (about 2.5 minutes; at most 3); then every check of
``bench/soak/``.

The soak runs in a process of its own: it sets Django up on its own cluster, not on the test
database.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from bench.soak import CHECKS, FAULT_NAMES
from bench.stack import REPO

pytestmark = [pytest.mark.integration, pytest.mark.long]

MINUTES = 3.0
# At most 20 s apart: the eight kinds fit in the first 160 s of the 180.
CHAOS_EVERY_S = ("12", "20")


@pytest.mark.timeout(600)
def test_a_short_soak_loses_doubles_and_leaves_nothing_behind(tmp_path):
    out = tmp_path / "out"
    soak = subprocess.run(
        [
            sys.executable,
            "-m",
            "bench.soak",
            "--minutes",
            str(MINUTES),
            "--chaos-every-s",
            *CHAOS_EVERY_S,
            "--program-s",
            "10",
            "--seed",
            "7",
            "--until-each-fault",
            "--out",
            str(out),
            "--work",
            str(tmp_path / "work"),
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=540,
        check=False,
    )
    told = f"{soak.stdout[-6000:]}\n{soak.stderr[-4000:]}"
    assert (out / "soak.json").exists(), told
    result = json.loads((out / "soak.json").read_text())
    misses = {CHECKS[key]: found for key, found in result["misses"].items() if found}
    assert not misses, f"{misses}\n{told}"
    assert soak.returncode == 0, told
    assert {fault["kind"] for fault in result["faults"]} == set(FAULT_NAMES)
    runs = result["runs"]
    assert {run["robot"] for run in runs} == {"mobile-1", "mobile-2"}
    assert any(run["nodes"] for run in runs), "no booking held a fixed node"
    assert result["leases"] >= sum(1 for run in runs if run["nodes"])
    assert result["samples_stored"] == result["samples_on_agents"] > 0
    assert (out / "soak.png").stat().st_size > 0
    assert "| PostgreSQL restart | 1 |" in (out / "soak.md").read_text()
