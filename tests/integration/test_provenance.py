"""Every run records how it was made, end to end with the real processes: the firmware build
the simulated robot reports, the agent's rail file (its hash), control rate and limits, as the
agent and the robot were started; restarted with another firmware build and rail file, the
next run records those, and the first keeps its own."""

from __future__ import annotations

import hashlib
import json
import time
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
import requests
from django.conf import settings
from django.utils import timezone

from basestation.telemetry.rail import DEFAULT_RAIL_PATH
from tests.factories import MobileResourceFactory, UserFactory, api_token
from tests.integration.stack import running_stack

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]

END_STATES = ("completed", "failed", "interrupted", "cancelled")


def _rail_file(path: Path, name: str) -> Path:
    """The default rail's geometry under another name: another file, another hash."""
    data = json.loads(DEFAULT_RAIL_PATH.read_text())
    data["name"] = name
    path.write_text(json.dumps(data, indent=1))
    return path


def _sim_config(path: Path, build_id: str) -> Path:
    path.write_text(f'[firmware]\nbuild_id = "{build_id}"\n')
    return path


BOOKED_S = 8


def _run_program(
    web: str, headers: dict[str, str], not_before: datetime | None = None
) -> tuple[dict[str, Any], datetime]:
    """Books the robot for a short program (no earlier than ``not_before``: a booking keeps its
    slot even when its run ends early), waits for the run to end; the run and the booking's
    end."""
    experiment = requests.post(
        f"{web}/api/v1/experiments/",
        json={
            "title": "provenance",
            "segments": [{"velocity_mps": 0.4, "direction": "cw", "duration_s": 2.0}],
        },
        headers=headers,
        timeout=10,
    )
    assert experiment.status_code == 201, experiment.text
    start = max(timezone.now() + timedelta(seconds=4), not_before or timezone.now())
    booking = requests.post(
        f"{web}/api/v1/reservations/",
        json={
            "resource": "mobile-1",
            "experiment": experiment.json()["id"],
            "start_at": start.isoformat(),
            "end_at": (start + timedelta(seconds=BOOKED_S)).isoformat(),
        },
        headers=headers,
        timeout=10,
    )
    assert booking.status_code == 201, booking.text
    run_id = booking.json()["run"]["id"]
    deadline = time.monotonic() + 60
    run: dict[str, Any] = {}
    while time.monotonic() < deadline:
        run = requests.get(f"{web}/api/v1/runs/{run_id}/", headers=headers, timeout=10).json()
        if run["state"] in END_STATES:
            break
        time.sleep(0.3)
    return run, datetime.fromisoformat(booking.json()["end_at"])


def test_the_stored_provenance_is_what_the_robot_and_the_agent_were_started_with(tmp_path):
    rail_1 = _rail_file(tmp_path / "rail-1.json", "roof, survey 1")
    agent_env = {
        "AGENT_CONTROL_HZ": "25",
        "AGENT_MAX_VELOCITY_MPS": "1.5",
        "AGENT_MAX_ACCEL_MPS2": "0.8",
        "AGENT_RAIL_FILE": str(rail_1),
        "AGENT_SIM_CONFIG": str(_sim_config(tmp_path / "sim-1.toml", "e2e-build-1")),
    }
    with running_stack(
        tmp_path / "var", broker_url=settings.CELERY_BROKER_URL, extra_env=agent_env
    ) as stack:
        robot = MobileResourceFactory(agent_url=stack.agent_url)
        # Booking and staging take the stricter of the robot's limits and those its agent
        # reported to the health sweep: book once the portal has heard them.
        deadline = time.monotonic() + 60
        while robot.agent_max_velocity_mps is None and time.monotonic() < deadline:
            time.sleep(0.2)
            robot.refresh_from_db()
        assert robot.agent_max_velocity_mps == 1.5, stack.output()
        user = UserFactory(username="gil")
        headers = {"Authorization": f"Token {api_token(user)}"}
        first, first_end = _run_program(stack.web, headers)
        assert first["state"] == "completed", (first.get("reason"), stack.output())

        staged = first["provenance"]["staged"]
        collected = first["provenance"]["collected"]
        for made in (staged, collected):
            assert made["firmware"]["build_id"] == "e2e-build-1"
            assert made["firmware"]["config"]["hard_max_velocity_mm_s"] == 4000
            agent = made["agent"]
            assert agent["interface"] == "sim"
            assert agent["control_hz"] == 25.0
            assert agent["max_velocity_mps"] == 1.5
            assert agent["max_accel_mps2"] == 0.8
            assert agent["robot_hard_max_velocity_mps"] == 4.0
            assert agent["rail"]["name"] == "roof, survey 1"
            assert agent["rail"]["file"] == str(rail_1)
            assert agent["rail"]["sha256"] == hashlib.sha256(rail_1.read_bytes()).hexdigest()
        # The limits sent are within the agent's: booking and staging take the stricter.
        assert staged["limits"]["max_velocity_mps"] <= 1.5
        assert staged["limits"]["max_accel_mps2"] <= 0.8
        assert collected["started_at"] is not None
        # The base station's clock as its loop wrote it when the run started and ended, and
        # in the state the agent reports now (this machine's clock does not change mid-test).
        assert stack.agent is not None
        on_agent = stack.agent.get_run(f"run-{first['id']}")["provenance"]
        assert collected["clock_at_start"] == on_agent["started"]["clock"]
        assert collected["clock_at_end"] == on_agent["ended"]["clock"]
        assert set(collected["clock_at_end"]) == {
            "synchronized",
            "offset_s",
            "max_error_s",
            "estimated_error_s",
        }
        clock_now = stack.agent.status()["clock_sync"]
        assert collected["clock_at_start"]["synchronized"] == clock_now["synchronized"]
        assert collected["clock_at_end"]["synchronized"] == clock_now["synchronized"]
        link = collected["link"]
        # One exchange a tick while the run held the robot: every sample, and any lost.
        assert link["answered"] == first["sample_count"] > 40
        assert link["exchanges"] == link["answered"] + link["lost"]
        assert link["rssi_dbm"]["min"] <= link["rssi_dbm"]["mean"] <= link["rssi_dbm"]["max"]

        # Another firmware build and another rail file: the next run says so.
        rail_2 = _rail_file(tmp_path / "rail-2.json", "roof, survey 2")
        stack.kill("agent")
        stack.env["AGENT_RAIL_FILE"] = str(rail_2)
        stack.env["AGENT_SIM_CONFIG"] = str(_sim_config(tmp_path / "sim-2.toml", "e2e-build-2"))
        stack.start("agent")
        stack.wait_ready("agent")
        second, _ = _run_program(stack.web, headers, not_before=first_end + timedelta(seconds=1))
        assert second["state"] == "completed", (second.get("reason"), stack.output())
        made = second["provenance"]["collected"]
        assert made["firmware"]["build_id"] == "e2e-build-2"
        assert made["agent"]["rail"]["sha256"] == hashlib.sha256(rail_2.read_bytes()).hexdigest()
        assert made["agent"]["rail"]["sha256"] != collected["agent"]["rail"]["sha256"]
        again = requests.get(
            f"{stack.web}/api/v1/runs/{first['id']}/", headers=headers, timeout=10
        ).json()
        assert again["provenance"] == first["provenance"]
