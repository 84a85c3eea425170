"""Each sample carries where the robot was: fix, position, thesis grid cell and lap."""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass
from pathlib import Path

from basestation.config import AgentConfig
from basestation.manager import RunManager
from basestation.robot import Command, Telemetry
from basestation.services import run_stage
from basestation.store import RunStore
from tests.basestation.conftest import TOKEN, run_body


@dataclass(frozen=True)
class PositionedTelemetry(Telemetry):
    fix_quality: int = 4
    lat_deg: float = 40.6343
    lon_deg: float = -8.6601
    grid_id: str = "A1"
    position_known: bool = True


class LappingRobot:
    """Goes round a 10 m rail at 5 m/s: a lap every two seconds."""

    rail_length_m = 10.0

    def __init__(self) -> None:
        self.track_m = 0.0
        self.last_s: float | None = None

    def exchange(self, command: Command, now_s: float) -> Telemetry:
        if self.last_s is not None:
            self.track_m = (self.track_m + 5.0 * (now_s - self.last_s)) % self.rail_length_m
        self.last_s = now_s
        return PositionedTelemetry(
            velocity_mps=5.0, direction="cw", battery_v=60.0, track_m=self.track_m
        )


def test_samples_carry_the_position_and_count_laps(tmp_path: Path) -> None:
    config = AgentConfig(token=TOKEN, data_dir=tmp_path, rail_length_m=10.0, robot="simple")
    store = RunStore(config.store_path)
    manager = RunManager(store=store, robot=LappingRobot(), config=config)  # type: ignore[arg-type]
    start_s = 1_000_000.0
    segments = [{"velocity_mps": 1.0, "direction": "cw", "duration_s": 7.0}]
    run_stage(
        store=store, manager=manager, config=config, run_id="laps",
        body=run_body(start_s, window_s=30.0, segments=segments), now_s=start_s - 10,
    )  # fmt: skip
    for k in range(0, 141):  # 7 s at 20 Hz
        manager.tick(start_s + k * 0.05)
    manager.writer.flush()
    samples = store.samples_after("laps", 0, 1000)
    assert samples[0].grid_id == "A1"
    assert (samples[0].fix_quality, samples[0].lat_deg) == (4, 40.6343)
    assert samples[0].lap == 0
    assert samples[-1].lap == 3  # 35 m on a 10 m rail
    laps = [s.lap for s in samples]
    assert laps == sorted(laps)
    manager.shutdown(start_s + 8)
    manager.writer.stop()
    store.close()


def test_an_older_store_gains_the_position_columns(tmp_path: Path) -> None:
    path = tmp_path / "runs.sqlite3"
    with sqlite3.connect(path) as conn:
        conn.executescript(
            "CREATE TABLE runs (id TEXT PRIMARY KEY, body TEXT NOT NULL, owner TEXT NOT NULL,"
            " title TEXT NOT NULL, start_at REAL NOT NULL, end_at REAL NOT NULL, state TEXT NOT"
            " NULL, reason TEXT, created_at REAL NOT NULL, updated_at REAL NOT NULL,"
            " started_at REAL, ended_at REAL);"
            "CREATE TABLE samples (run_id TEXT NOT NULL REFERENCES runs (id), seq INTEGER NOT"
            " NULL, t REAL NOT NULL, segment INTEGER, commanded_velocity_mps REAL NOT NULL,"
            " velocity_mps REAL NOT NULL, direction TEXT NOT NULL, battery_v REAL NOT NULL,"
            " track_m REAL NOT NULL, PRIMARY KEY (run_id, seq)) WITHOUT ROWID;"
            "INSERT INTO runs VALUES ('old', '{}', 'a', 't', 1, 2, 'completed', NULL, 1, 2, 1, 2);"
            "INSERT INTO samples VALUES ('old', 1, 1.5, 0, 0.5, 0.5, 'cw', 60.0, 3.0);"
        )
    store = RunStore(path)
    (sample,) = store.samples_after("old", 0, 10)
    assert (sample.track_m, sample.grid_id, sample.lap) == (3.0, None, None)
    columns = {row[1] for row in sqlite3.connect(path).execute("PRAGMA table_info(samples)")}
    assert {"fix_quality", "lat_deg", "lon_deg", "grid_id", "lap"} <= columns
    store.close()
