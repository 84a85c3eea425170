"""Telemetry processing on the base station: battery median filter, GPS fix freshness,
projection onto the rail with the thesis grid id, laps and passes."""

from basestation.telemetry.battery import DEFAULT_BATTERY_WINDOW, BatteryFilter, MedianFilter
from basestation.telemetry.gps import (
    DEFAULT_STALE_AFTER_S,
    FIX_QUALITY_NAMES,
    GpsFix,
    GpsTracker,
)
from basestation.telemetry.laps import LapCounter, Pass, unwrap_track, wrap_delta_m
from basestation.telemetry.rail import (
    DEFAULT_GRID_POINTS,
    DEFAULT_RAIL_PATH,
    THESIS_CENTRE,
    LocalFrame,
    Rail,
    RailConfigError,
    RailPosition,
    grid_id,
    grid_ids,
)

__all__ = [
    "DEFAULT_BATTERY_WINDOW",
    "DEFAULT_GRID_POINTS",
    "DEFAULT_RAIL_PATH",
    "DEFAULT_STALE_AFTER_S",
    "FIX_QUALITY_NAMES",
    "THESIS_CENTRE",
    "BatteryFilter",
    "GpsFix",
    "GpsTracker",
    "LapCounter",
    "LocalFrame",
    "MedianFilter",
    "Pass",
    "Rail",
    "RailConfigError",
    "RailPosition",
    "grid_id",
    "grid_ids",
    "unwrap_track",
    "wrap_delta_m",
]
