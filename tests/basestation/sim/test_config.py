"""Rail geometry and simulator configuration: defaults, files, and clear errors."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from basestation.sim.config import SimConfig, SimConfigError
from basestation.sim.rail import BUILDING_CENTRE, RailConfigError, RailGeometry


def test_the_default_rail_is_a_square_around_the_building_with_cardinal_corners() -> None:
    rail = RailGeometry.default()
    assert rail.length_m == pytest.approx(120.0)
    lat0, lon0 = BUILDING_CENTRE
    north, east, south, west = (rail.lat_lon_at(s) for s in (0.0, 30.0, 60.0, 90.0))
    assert north[0] > lat0
    assert north[1] == pytest.approx(lon0)
    assert east[1] > lon0
    assert east[0] == pytest.approx(lat0)
    assert south[0] < lat0
    assert west[1] < lon0
    assert [rail.side_at(s) for s in (1.0, 31.0, 61.0, 91.0)] == ["A", "B", "C", "D"]
    for track_m in (0.0, 7.5, 29.99, 45.0, 119.0):
        assert rail.project(*rail.lat_lon_at(track_m)) == pytest.approx(track_m, abs=1e-6)
    assert rail.wrap(121.0) == pytest.approx(1.0)
    assert rail.wrap(-1.0) == pytest.approx(119.0)


def test_a_rail_from_latitudes_and_longitudes() -> None:
    corners = [[40.6342, -8.6601], [40.6342, -8.6599], [40.6340, -8.6599], [40.6340, -8.6601]]
    rail = RailGeometry.from_mapping({"vertices": corners, "sides": ["N", "E", "S", "W"]})
    side_ns_m = math.radians(0.0002) * 6_371_008.8
    side_ew_m = side_ns_m * math.cos(math.radians(40.6341))
    assert rail.length_m == pytest.approx(2 * (side_ns_m + side_ew_m), rel=1e-6)
    assert rail.lat_lon_at(0.0) == pytest.approx((40.6342, -8.6601))


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"vertices_m": [[0, 0], [10, 0]]}, "at least 3 vertices"),
        ({"vertices_m": [[0, 0], [10, 0], [10, 0], [0, 10]]}, "repeated vertex"),
        ({"vertices_m": [[0, 0], [10, 10], [10, 0], [0, 10]]}, "cross"),
        ({"vertices_m": [[0, 0], [10, 0], [0, "x"]]}, r"vertices_m\[2\]\[1\] must be a number"),
        ({"vertices_m": [[0, 0], [10, 0], [0, math.inf]]}, "finite"),
        ({"vertices": [[91, 0], [0, 1], [1, 1]]}, "latitude 91"),
        ({"vertices_m": [[0, 0], [1, 0], [0, 1]], "vertices": []}, "exactly one of"),
        ({"vertices_m": [[0, 0], [10, 0], [0, 10]], "colour": "red"}, "unknown key.*colour"),
        ({"vertices_m": [[0, 0], [10, 0], [0, 10]], "sides": ["A", "B"]}, "3 segments"),
        ({"vertices_m": [[0, 0], [10, 0], [0, 10]], "sides": ["A", "A", "B"]}, "unique"),
        ({"vertices_m": [[0, 0], [0.1, 0], [0, 0.1]]}, "not in 1..100000"),
    ],
)
def test_a_bad_rail_is_refused_with_a_message_naming_the_problem(
    table: dict[str, object], message: str
) -> None:
    with pytest.raises(RailConfigError, match=message):
        RailGeometry.from_mapping(table)


def test_a_toml_file_configures_everything(tmp_path: Path) -> None:
    path = tmp_path / "sim.toml"
    path.write_text(
        """
seed = 4
start_track_m = 10.0
[rail]
centre = [40.634172, -8.660015]
vertices_m = [[0.0, 20.0], [20.0, 0.0], [0.0, -20.0], [-20.0, 0.0]]
sides = ["A", "B", "C", "D"]
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
""",
        encoding="utf-8",
    )
    config = SimConfig.load(path)
    assert config.seed == 4
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
    assert config.rail == RailGeometry.default()


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
        ("[rail]\nvertices_m = [[0, 0]]\n", r"sim\.toml: rail: a closed rail needs at least 3"),
        ("physics = [1, 2\n", "not valid TOML"),
    ],
)
def test_a_bad_config_file_names_the_key(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "sim.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SimConfigError if "rail" not in text else RailConfigError, match=message):
        SimConfig.load(path)


def test_a_missing_or_unknown_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(SimConfigError, match="cannot read"):
        SimConfig.load(tmp_path / "nope.toml")
    (tmp_path / "sim.yaml").write_text("seed: 1", encoding="utf-8")
    with pytest.raises(SimConfigError, match=r"use a \.json or \.toml file"):
        SimConfig.load(tmp_path / "sim.yaml")
