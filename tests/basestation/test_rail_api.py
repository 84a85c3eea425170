"""``GET /api/v1/rail``: the rail as the control loop read it, drawn for a map of the roof;
and the rail file's fixed nodes."""

from __future__ import annotations

import itertools
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from flask import Flask

from basestation.app import create_app
from basestation.config import AgentConfig
from basestation.runtime import get_runtime
from basestation.telemetry.rail import DEFAULT_RAIL_PATH, Rail, RailConfigError

TOKEN = "r" * 32
AUTH = {"Authorization": f"Bearer {TOKEN}"}
NODES = [
    {"name": "node-01", "lat": 40.63431, "lon": -8.66012},
    {"name": "node-02", "lat": 40.63400, "lon": -8.65990},
]


def _rail_file(path: Path, **extra: Any) -> Path:
    data = json.loads(DEFAULT_RAIL_PATH.read_text())
    data.update(extra)
    path.write_text(json.dumps(data))
    return path


@pytest.fixture
def rail_file(tmp_path: Path) -> Path:
    return _rail_file(tmp_path / "rail.json", name="roof with nodes", nodes=NODES)


@pytest.fixture
def sim_app(tmp_path: Path, rail_file: Path) -> Iterator[Flask]:
    config = AgentConfig(token=TOKEN, data_dir=tmp_path / "agent", robot="sim", rail_file=rail_file)
    app = create_app(config, start_control_loop=False)
    yield app
    get_runtime(app).close()


def test_the_default_rail_is_drawn_clockwise_from_its_origin_with_its_grid_cells() -> None:
    drawing = Rail.default().drawing()
    assert drawing["length_m"] == pytest.approx(120.0, abs=0.05)
    points = drawing["points"]
    # North, east, south, west: clockwise seen from above, 30 m apart.
    assert [p["track_m"] for p in points] == pytest.approx([0.0, 30.0, 60.0, 90.0], abs=0.05)
    assert points[1]["x_m"] > 20
    assert abs(points[1]["y_m"]) < 0.01
    assert drawing["origin"] == {"x_m": points[0]["x_m"], "y_m": points[0]["y_m"]}
    cells = drawing["cells"]
    assert [c["id"] for c in cells] == Rail.default().grid_ids
    assert cells[0]["from_m"] == 0.0
    assert cells[-1]["to_m"] == pytest.approx(drawing["length_m"], abs=0.001)
    for before, after in itertools.pairwise(cells):
        assert before["to_m"] == after["from_m"]
    # Each side's four cells are equal angles from the centre: the middle two are shorter.
    side_a = [c["to_m"] - c["from_m"] for c in cells[:4]]
    assert side_a[0] == pytest.approx(side_a[3], abs=0.1)
    assert side_a[1] < side_a[0]
    assert drawing["nodes"] == []


def test_a_rail_file_places_the_fixed_nodes(rail_file: Path) -> None:
    nodes = Rail.from_file(rail_file).drawing()["nodes"]
    assert [n["name"] for n in nodes] == ["node-01", "node-02"]
    # node-01 lies north-west of the centre, node-02 south-east.
    assert nodes[0]["x_m"] < 0 < nodes[0]["y_m"]
    assert nodes[1]["y_m"] < 0 < nodes[1]["x_m"]


@pytest.mark.parametrize(
    ("nodes", "field", "message"),
    [
        ("node-01", "nodes", "must be a list"),
        ([{"name": "", "lat": 40.6, "lon": -8.6}], "nodes[0].name", "non-empty string"),
        ([{"name": "n", "lat": 40.6}], "nodes[0].lon", "is required"),
        ([{"name": "n", "lat": 40.6, "lon": -8.6, "height": 3}], "nodes[0].height", "unknown"),
        ([NODES[0], NODES[0]], "nodes[1].name", "listed twice"),
        ([{"name": "far", "lat": 41.6, "lon": -8.6}], "nodes[0]", "km from the centre"),
    ],
)
def test_a_bad_node_names_its_field(tmp_path: Path, nodes: Any, field: str, message: str) -> None:
    path = _rail_file(tmp_path / "rail.json", nodes=nodes)
    with pytest.raises(RailConfigError) as caught:
        Rail.from_file(path)
    assert caught.value.field == field
    assert message in caught.value.message


def test_the_agent_serves_the_rail_its_loop_drives(sim_app: Flask, rail_file: Path) -> None:
    client = sim_app.test_client()
    assert client.get("/api/v1/rail").status_code == 401
    response = client.get("/api/v1/rail", headers=AUTH)
    assert response.status_code == 200
    body = response.get_json()
    assert body["geometry"] is True
    assert body["name"] == "roof with nodes"
    assert body == {"geometry": True, **Rail.from_file(rail_file).drawing()}


def test_a_rail_file_changed_since_the_start_is_reported_not_drawn(
    sim_app: Flask, rail_file: Path
) -> None:
    _rail_file(rail_file, name="moved overnight")
    response = sim_app.test_client().get("/api/v1/rail", headers=AUTH)
    assert response.status_code == 409
    assert response.get_json()["error"] == "rail_changed"


def test_the_kinematic_model_has_only_a_length(client, auth) -> None:
    response = client.get("/api/v1/rail", headers=auth)
    assert response.status_code == 200
    assert response.get_json() == {"geometry": False, "length_m": 120.0}
