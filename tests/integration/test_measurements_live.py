"""Measurements pushed live from the simulated robot's node, end to end with real processes.

A run on the simulated robot; while it goes on, ``python -m basestation.sim.rssi`` (the
synthetic signal strength of a fixed node, a log-distance path loss with seeded shadowing)
follows its samples through the API and sends a reading for each. The per-cell means the
portal computes must be within the model's shadowing of the model's own values: those are
computed here from the model and the samples' places, not with the portal's code.
"""

from __future__ import annotations

import subprocess
import sys
from collections import defaultdict

import pytest
import requests

from basestation.sim.rssi import DEFAULT_NODE_AT, PathLoss, distance_m
from basestation.telemetry.rail import Rail
from bench.stack import REPO
from tests.factories import MobileResourceFactory
from tests.integration.experimenter import Experimenter

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]

SEGMENT_S = 16.0
VELOCITY_MPS = 1.0
SEED = 7


def _samples(web: str, run_id: int, headers: dict[str, str]) -> list[dict]:
    samples, after = [], 0
    while True:
        page = requests.get(
            f"{web}/api/v1/runs/{run_id}/samples/",
            params={"after": after, "limit": 1000},
            headers=headers,
            timeout=10,
        ).json()
        if not page["samples"]:
            return samples
        samples += page["samples"]
        after = page["last_seq"]


def test_synthetic_rssi_pushed_live_is_placed_in_the_cells_the_model_says(stack):
    MobileResourceFactory(agent_url=stack["agent_url"])
    erin = Experimenter(stack, "erin")
    headers = dict(erin.session.headers)
    token = headers["Authorization"].removeprefix("Token ")
    web = stack["web"]
    segments = [{"velocity_mps": VELOCITY_MPS, "direction": "cw", "duration_s": SEGMENT_S}]
    run_id = erin.run("mobile-1", ahead_s=4.0, program_s=SEGMENT_S, segments=segments)
    pusher = subprocess.run(
        [sys.executable, "-m", "basestation.sim.rssi", "--portal", web, "--token", token,
         "--run", str(run_id), "--seed", str(SEED), "--poll-s", "0.5"],
        cwd=REPO, capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    logs = "\n".join(p.output() for p in stack["procs"])
    assert pusher.returncode == 0, f"{pusher.stdout}\n{pusher.stderr}\n{logs}"
    run = requests.get(f"{web}/api/v1/runs/{run_id}/", headers=headers, timeout=10).json()
    assert run["state"] == "completed", logs
    samples = _samples(web, run_id, headers)
    assert f"rssi: {len(samples)} readings sent" in pusher.stdout

    series = requests.get(
        f"{web}/api/v1/runs/{run_id}/measurements/rssi/", headers=headers, timeout=10
    ).json()
    summary = series["summary"]["columns"]["rssi"]
    # Each reading was taken at a sample's time: each is placed, on that sample.
    assert series["point_count"] == len(samples)
    assert summary["where"] == {"placed": len(samples), "before": 0, "after": 0, "gap": 0}

    # The model's own value at each sample's place, by the sample's cell.
    model, rail = PathLoss(), Rail.default()
    expected: dict[str, list[float]] = defaultdict(list)
    for sample in samples:
        if sample["grid_id"]:
            distance = distance_m(rail, DEFAULT_NODE_AT, sample["track_m"])
            expected[sample["grid_id"]].append(model.mean_dbm(distance))
    cells = {row["cell"]: row for row in summary["by_cell"]}
    assert len(cells) >= 2, summary["by_cell"]
    assert set(cells) == set(expected)
    for cell, values in expected.items():
        assert cells[cell]["count"] == len(values)
        model_mean = sum(values) / len(values)
        assert abs(cells[cell]["mean"] - model_mean) <= model.shadowing_db, (cell, cells[cell])
