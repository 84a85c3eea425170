"""The dry run's simulator (``basestation/dryrun.py``): the base station's run manager driving
the kinematic model in simulated time, as ``python -m basestation.dryrun`` does for the portal."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys

import pytest

from basestation.dryrun import MAX_PROGRAM_S, DryRunRefused, dry_run
from bench.stack import REPO

HZ = 20.0


def test_a_program_runs_to_its_end_in_simulated_time_with_the_robots_ramps():
    segments = [
        {"velocity_mps": 0.5, "direction": "cw", "duration_s": 10.0},
        {"velocity_mps": 0.8, "direction": "ccw", "duration_s": 5.0},
    ]
    result = dry_run(segments, max_velocity_mps=1.0, max_accel_mps2=0.5, rail_length_m=50.0)
    assert result["state"] == "completed", result["reason"]
    samples = result["samples"]
    assert [s["seq"] for s in samples] == list(range(1, len(samples) + 1))
    # One sample a control tick while the program runs, then the braking.
    assert 15.0 * HZ <= len(samples) <= (15.0 + 5.0) * HZ
    assert {s["segment"] for s in samples} >= {0, 1}
    # The ramps: the robot never changes speed faster than its limit allows (with the
    # model's noise on the measurement).
    signed = [(1 if s["direction"] == "cw" else -1) * s["velocity_mps"] for s in samples]
    steps = [abs(b - a) for a, b in itertools.pairwise(signed)]
    assert max(steps) <= 0.5 / HZ + 0.05
    assert max(abs(v) for v in signed) <= 1.0 + 0.05

    # 5 m clockwise, then 4 m back, as the ramps make it: a change of velocity by dv at
    # 0.5 m/s² takes |dv| / 0.5 s and leaves the robot dv * that / 2 behind an instant change;
    # the stop after the last segment is driven past the program's end.
    def behind_m(dv: float) -> float:
        return dv * (abs(dv) / 0.5) / 2

    expected_m = 0.5 * 10 - 0.8 * 5 - behind_m(0.5) - behind_m(-1.3) - behind_m(0.8)
    assert samples[-1]["track_m"] == pytest.approx(expected_m, abs=0.05)


def test_what_the_agent_would_refuse_is_refused_before_anything_runs():
    too_fast = [{"velocity_mps": 1.5, "direction": "cw", "duration_s": 2.0}]
    with pytest.raises(DryRunRefused, match="refused"):
        dry_run(too_fast, max_velocity_mps=1.0, max_accel_mps2=0.5)
    too_long = [{"velocity_mps": 0.1, "direction": "cw", "duration_s": MAX_PROGRAM_S + 1}]
    with pytest.raises(DryRunRefused, match="at most"):
        dry_run(too_long, max_velocity_mps=1.0, max_accel_mps2=0.5)
    with pytest.raises(DryRunRefused, match="duration_s"):
        dry_run([{"velocity_mps": 0.1}], max_velocity_mps=1.0, max_accel_mps2=0.5)


def _process(request: object) -> tuple[int, dict]:
    done = subprocess.run(
        [sys.executable, "-m", "basestation.dryrun"],
        input=json.dumps(request),
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
        check=False,
    )
    return done.returncode, json.loads(done.stdout)


def test_the_process_answers_in_json_and_says_why_it_refuses():
    code, answer = _process(
        {
            "segments": [{"velocity_mps": 0.3, "direction": "cw", "duration_s": 2.0}],
            "limits": {"max_velocity_mps": 1.0, "max_accel_mps2": 1.0},
            "rail_length_m": 30.0,
        }
    )
    assert code == 0
    assert answer["state"] == "completed"
    assert answer["rail_length_m"] == 30.0
    assert len(answer["samples"]) >= 2.0 * HZ
    code, answer = _process({"segments": []})
    assert code == 2
    assert answer["state"] == "failed"
    assert "limits" in answer["reason"]
    assert answer["samples"] == []
