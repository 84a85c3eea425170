"""What every run records of how it was made: the agent, the robot's firmware, the clock,
the link (basestation/provenance.py), from the manager's tick to ``GET /runs/{id}``."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from flask.testing import FlaskClient

from basestation.config import AgentConfig, ConfigError
from basestation.program import parse_run_body
from basestation.provenance import AGENT_VERSION, RunLinkTally, agent_facts
from basestation.robot import Telemetry
from basestation.robots import build_robot
from basestation.runtime import AgentRuntime
from basestation.services import run_withdraw
from basestation.telemetry.rail import DEFAULT_RAIL_PATH, Rail
from tests.basestation.conftest import run_body

T0 = 1_900_000_000.0
Drive = Callable[[float, float], float]
CLOCK_KEYS = {"synchronized", "offset_s", "max_error_s", "estimated_error_s"}


def _stage(runtime: AgentRuntime, run_id: str, start_s: float) -> None:
    spec = parse_run_body(run_body(start_s))
    runtime.store.stage_run(run_id, spec, now_s=start_s - 60.0, admit=lambda _: None)
    runtime.manager.notify_runs_changed()


def _provenance(client: FlaskClient, auth: dict[str, str], run_id: str) -> dict[str, Any]:
    answer = client.get(f"/api/v1/runs/{run_id}", headers=auth)
    assert answer.status_code == 200
    provenance: dict[str, Any] = answer.get_json()["provenance"]
    return provenance


def test_a_run_records_the_agent_the_clock_and_the_link_as_it_starts_and_ends(
    runtime: AgentRuntime, drive: Drive, client: FlaskClient, auth: dict[str, str]
) -> None:
    _stage(runtime, "run-1", T0 + 1.0)
    drive(T0, T0 + 0.5)
    staged = _provenance(client, auth, "run-1")
    # Before it starts: what the agent is now, nothing recorded yet.
    assert staged["started"] is None
    assert staged["ended"] is None
    assert staged["agent"]["control_hz"] == 20.0
    assert staged["firmware"] is None  # the kinematic model has no firmware to ask

    drive(T0 + 0.5, T0 + 12.0)
    record = runtime.store.get_run("run-1")
    assert record is not None
    assert record.state == "completed"
    runtime.manager.writer.flush()
    provenance = _provenance(client, auth, "run-1")
    started, ended = provenance["started"], provenance["ended"]
    assert started["at"].startswith("2030-03-17T17:46:41")  # T0 + 1 s
    assert started["agent"] == {
        "version": AGENT_VERSION,
        "resource": "mobile-1",
        "interface": "simple",
        "control_hz": 20.0,
        "max_velocity_mps": 2.0,
        "max_accel_mps2": 1.0,
        "robot_hard_max_velocity_mps": None,
        "robot_confirmed_limits": False,
        "low_battery_v": 50.0,
        "rail": {"name": None, "file": None, "sha256": None, "length_m": 120.0},
    }
    assert started["firmware"] is None
    assert set(started["clock"]) == CLOCK_KEYS == set(ended["clock"])
    samples = runtime.store.sample_stats("run-1").count
    # One exchange per tick while the run held the robot, each answered by the model.
    assert ended["link"] == {
        "exchanges": samples,
        "answered": samples,
        "lost": 0,
        "loss_pct": 0.0,
        "rssi_dbm": None,
        "robot_rssi_dbm": None,
    }


def test_a_run_aborted_from_outside_the_loop_records_its_end_too(
    runtime: AgentRuntime, drive: Drive, client: FlaskClient, auth: dict[str, str]
) -> None:
    _stage(runtime, "run-1", T0 + 1.0)
    drive(T0, T0 + 3.0)
    run_withdraw(store=runtime.store, manager=runtime.manager, run_id="run-1", now_s=T0 + 3.0)
    drive(T0 + 3.0, T0 + 5.0)
    runtime.manager.writer.flush()
    provenance = _provenance(client, auth, "run-1")
    assert runtime.store.get_run("run-1").state == "aborted"  # type: ignore[union-attr]
    assert provenance["ended"] is not None
    assert 0 < provenance["ended"]["link"]["exchanges"] <= 2.1 * 20


def test_the_link_tally_counts_losses_and_rssi_over_the_run() -> None:
    tally = RunLinkTally("run-1")
    answer = Telemetry(velocity_mps=0.0, direction="cw", battery_v=60.0, track_m=0.0)
    radio = type("RadioAnswer", (), {"rssi_dbm": -60.0, "robot_rssi_dbm": -58})
    for rssi, robot_rssi in ((-60.0, -58), (-70.0, -66)):
        radio.rssi_dbm, radio.robot_rssi_dbm = rssi, robot_rssi
        tally.add(radio())  # type: ignore[arg-type]
    tally.add(None)
    tally.add(answer)  # a model without a radio: counted, no RSSI
    assert tally.to_json_dict() == {
        "exchanges": 4,
        "answered": 3,
        "lost": 1,
        "loss_pct": 25.0,
        "rssi_dbm": {"min": -70.0, "mean": -65.0, "max": -60.0},
        "robot_rssi_dbm": {"min": -66.0, "mean": -62.0, "max": -58.0},
    }


def _rail_file(path: Path, name: str) -> Path:
    data = json.loads(DEFAULT_RAIL_PATH.read_text())
    data["name"] = name
    path.write_text(json.dumps(data))
    return path


def test_the_simulated_robot_reports_its_build_and_the_rail_file_is_hashed(
    tmp_path: Path,
) -> None:
    sim_config = tmp_path / "sim.toml"
    sim_config.write_text('[firmware]\nbuild_id = "bench-7"\nhard_max_velocity_mm_s = 3500\n')
    rail_file = _rail_file(tmp_path / "rail.json", "roof, surveyed 2026")
    config = AgentConfig(
        token="t" * 32,
        data_dir=tmp_path / "agent",
        robot="sim",
        rail_file=rail_file,
        sim_config=sim_config,
    )
    robot: Any = build_robot(config)
    try:
        assert robot.identity is not None
        assert robot.identity.build_id == "bench-7"
        assert robot.identity.config["hard_max_velocity_mm_s"] == 3500
        assert robot.identity.config["dead_man_ms"] == 500
        facts = agent_facts(config, limits=robot.limits, rail=robot.rail)
    finally:
        robot.close()
    assert facts["robot_hard_max_velocity_mps"] == 3.5
    assert facts["rail"] == {
        "name": "roof, surveyed 2026",
        "file": str(rail_file),
        "sha256": hashlib.sha256(rail_file.read_bytes()).hexdigest(),
        "length_m": pytest.approx(Rail.from_file(rail_file).length_m),
    }
    # Another rail file (here only its name differs) is another rail in the record.
    _rail_file(rail_file, "roof, resurveyed")
    again = agent_facts(config, limits=None, rail=Rail.from_file(rail_file))
    assert again["rail"]["sha256"] != facts["rail"]["sha256"]


def test_a_bad_simulator_configuration_stops_the_agent_with_its_name(tmp_path: Path) -> None:
    sim_config = tmp_path / "sim.toml"
    sim_config.write_text('[firmware]\nbuild_id = "far too long a build id"\n')
    config = AgentConfig(
        token="t" * 32, data_dir=tmp_path / "agent", robot="sim", sim_config=sim_config
    )
    with pytest.raises(ConfigError) as caught:
        build_robot(config)
    assert "AGENT_SIM_CONFIG" in str(caught.value)
    assert "build_id must be printable ASCII of at most 16 characters" in str(caught.value)
