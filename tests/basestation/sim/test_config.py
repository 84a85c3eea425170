"""Simulator configuration: defaults, files, the agent's rail, and clear errors."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from basestation.sim.config import SimConfig, SimConfigError
from basestation.telemetry.rail import DEFAULT_RAIL_PATH, THESIS_CENTRE, LocalFrame, Rail

CENTRE = LocalFrame(*THESIS_CENTRE)


def diamond(half_diagonal_m: float) -> list[dict[str, float]]:
    """Corners north, east, south and west of the thesis centre, in the agent's format."""
    h = half_diagonal_m
    corners = [CENTRE.to_lat_lon(x, y) for x, y in ((0, h), (h, 0), (0, -h), (-h, 0))]
    return [{"lat": lat, "lon": lon} for lat, lon in corners]


def toml_points(points: list[dict[str, float]]) -> str:
    return ", ".join(f"{{lat = {p['lat']!r}, lon = {p['lon']!r}}}" for p in points)


def test_the_default_simulated_rail_is_the_agents_default_rail() -> None:
    rail, agents = SimConfig().rail, Rail.default()
    assert rail.points == agents.points
    assert rail.length_m == agents.length_m == pytest.approx(120.0, abs=0.05)
    assert rail.point_at(0.0) == agents.point_at(0.0)  # the same origin


def test_a_toml_file_configures_everything(tmp_path: Path) -> None:
    path = tmp_path / "sim.toml"
    path.write_text(
        """
seed = 4
start_track_m = 10.0
[physics]
mass_kg = 90
[battery]
initial_soc = 0.9
[gps]
fix = "rtk_float"
[radio]
network_id = 7
aes_key_hex = "00112233445566778899aabbccddeeff"
[firmware]
max_velocity_mm_s = 3000
[rail]
name = "inline"
centre = {lat = 40.634172, lon = -8.660015}
points = [{points}]
""".replace("{points}", toml_points(diamond(20.0))),
        encoding="utf-8",
    )
    config = SimConfig.load(path)
    assert config.seed == 4
    assert config.rail.name == "inline"
    assert config.rail.length_m == pytest.approx(4 * 20 * math.sqrt(2))
    assert config.physics.mass_kg == 90.0
    assert config.gps.model().sigma_m == 0.3
    assert config.radio.aes_key == bytes.fromhex("00112233445566778899aabbccddeeff")
    assert "0011" not in repr(config.radio)
    assert config.firmware == {"max_velocity_mm_s": 3000}


def test_a_json_file_works_too(tmp_path: Path) -> None:
    path = tmp_path / "sim.json"
    path.write_text(json.dumps({"gps": {"fix": "gps"}, "firmware": {"accel_mm_s2": 500}}))
    config = SimConfig.load(path)
    assert config.gps.fix == "gps"
    assert config.rail.points == Rail.default().points


def test_rail_file_names_the_same_file_the_agent_reads(tmp_path: Path) -> None:
    rails = tmp_path / "rails"
    rails.mkdir()
    (rails / "roof.json").write_text(json.dumps({"name": "roof", "points": diamond(25.0)}))
    (tmp_path / "sim.toml").write_text('rail_file = "rails/roof.json"\n', encoding="utf-8")
    config = SimConfig.load(tmp_path / "sim.toml")  # relative to the config file, not the cwd
    agents = Rail.from_file(rails / "roof.json")  # what AGENT_RAIL_FILE=rails/roof.json gives
    assert config.rail.name == "roof"
    assert config.rail.points == agents.points
    assert config.rail.length_m == agents.length_m == pytest.approx(4 * 25 * math.sqrt(2))
    absolute = SimConfig.from_mapping({"rail_file": str(DEFAULT_RAIL_PATH)})
    assert absolute.rail.points == Rail.default().points


def test_an_inline_rail_is_checked_by_the_agents_rules_with_the_same_field_names() -> None:
    points = diamond(20.0)
    points[2] = {"lat": 91, "lon": points[2]["lon"]}
    with pytest.raises(SimConfigError) as caught:
        SimConfig.from_mapping({"rail": {"points": points}}, where="sim.toml")
    assert str(caught.value) == "sim.toml: rail.points[2].lat: must be between -90 and 90, got 91"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[physics]\nmass_kg = -1\n", r"physics\.mass_kg = -1 not in 1\.\.1000"),
        ("[physics]\nmass = 1\n", r"unknown key\(s\) mass"),
        ("[gps]\nfix = 'perfect'\n", "'perfect' is not one of"),
        ("[radio]\naes_key_hex = 'abcd'\n", "32 hex digits"),
        ("[radio]\nhigh_power = 1\n", "true or false"),
        ("[firmware]\ndead_man_ms = 0\n", r"dead_man_ms = 0 not in 1\.\.65535"),
        ("[firmware]\nmax_velocity_mm_s = 70000\n", "not in 0..65535"),
        ("[firmware]\nwarp = 9\n", "unknown key 'warp'"),
        ("[firmware]\nnode = 9\n", r"set radio\.node instead"),
        ("[battery]\nempty_v = 13.0\n", "full_v must be above"),
        ("seed = 'x'\n", "seed must be an integer"),
        ("[rail]\npoints = [{lat = 40.6, lon = -8.6}]\n", r"sim\.toml: rail\.points: needs 3"),
        ("[rail]\ncolour = 'red'\n", r"sim\.toml: rail\.colour: unknown field"),
        ("rail = [1, 2]\n", "sim.toml: rail: must be an object"),
        ("rail_file = 3\n", "rail_file must be the path of a rail file"),
        ("rail_file = 'nowhere.json'\n", r"sim\.toml: rail_file: file: cannot read"),
        ("rail_file = 'r.json'\n[rail]\nname = 'x'\n", "keep one of them"),
        ("physics = [1, 2\n", "not valid TOML"),
        ("flashed = 'yes'\n", "true or false"),
        ("flashed = true\n[firmware]\ndead_man_ms = 300\n", "the flashed image's is compiled in"),
    ],
)
def test_a_bad_config_file_names_the_key(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "sim.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SimConfigError, match=message):
        SimConfig.load(path)


def test_a_bad_rail_file_is_named_with_the_field_at_fault(tmp_path: Path) -> None:
    body: dict[str, Any] = {"points": diamond(20.0)}
    body["points"][1]["lon"] = "east"
    (tmp_path / "rail.json").write_text(json.dumps(body), encoding="utf-8")
    (tmp_path / "sim.toml").write_text("rail_file = 'rail.json'\n", encoding="utf-8")
    with pytest.raises(SimConfigError) as caught:
        SimConfig.load(tmp_path / "sim.toml")
    message = str(caught.value)
    assert message.startswith(f"{tmp_path / 'sim.toml'}: rail_file: points[1].lon: must be a")
    assert str(tmp_path / "rail.json") in message


def test_a_missing_or_unknown_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(SimConfigError, match="cannot read"):
        SimConfig.load(tmp_path / "nope.toml")
    (tmp_path / "sim.yaml").write_text("seed: 1", encoding="utf-8")
    with pytest.raises(SimConfigError, match=r"use a \.json or \.toml file"):
        SimConfig.load(tmp_path / "sim.yaml")
