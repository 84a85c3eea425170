"""How this agent drives its robot, for the record every run keeps ("how this run was made").

The agent says it in every run's answer (``GET /runs/{id}`` ``provenance``, docs/agent-api.md):

- ``agent``: this agent's version, resource, robot interface, control rate, effective limits
  and rail (its file and the SHA-256 of the file's bytes);
- ``firmware``: what the robot's firmware said of itself at start-up (identity frame,
  docs/protocol.md §2.6), or None when it did not say;
- ``started``/``ended``: what the control loop recorded as the run started and ended: the same
  facts as they were then, the base station's clock-sync state, and the radio link over the
  run (:class:`RunLinkTally`).

A reviewer asking months later "which firmware, which limits, which rail, was the clock in
sync" reads the answer here; nothing in it is typed in by hand.
"""

from __future__ import annotations

import hashlib
import logging
import math
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from basestation.config import AgentConfig
from basestation.robot import RobotIdentity, RobotLimits, Telemetry
from basestation.system import clock_sync
from basestation.telemetry.rail import DEFAULT_RAIL_PATH, Rail

logger = logging.getLogger(__name__)

try:
    AGENT_VERSION = version("amazing-mobile-node")
except PackageNotFoundError:  # running from a source tree that was never installed
    AGENT_VERSION = "0+unknown"


def _sha256(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as exc:
        logger.warning("cannot hash the rail file %s: %s", path, exc)
        return None


def rail_facts(config: AgentConfig, rail: Rail | None) -> dict[str, Any]:
    """The rail the samples' positions are projected onto: its name, the file it was read
    from (None: the built-in default), the SHA-256 of that file's bytes and its length.
    Without a rail geometry (the kinematic model) only the configured length."""
    if rail is None:
        return {"name": None, "file": None, "sha256": None, "length_m": config.rail_length_m}
    path = config.rail_file if config.rail_file is not None else DEFAULT_RAIL_PATH
    return {
        "name": rail.name,
        "file": None if config.rail_file is None else str(config.rail_file),
        "sha256": _sha256(path),
        "length_m": rail.length_m,
    }


def agent_facts(
    config: AgentConfig, *, limits: RobotLimits | None, rail: Rail | None
) -> dict[str, Any]:
    """This agent as it drives runs: version, resource, robot interface, control rate, the
    effective limits (the agent's, within the robot's hard maximum) and the rail."""
    hard_max = None if limits is None else limits.hard_max_velocity_mps
    velocity = config.max_velocity_mps
    return {
        "version": AGENT_VERSION,
        "resource": config.resource,
        "interface": config.robot,
        "control_hz": config.control_hz,
        "max_velocity_mps": velocity if hard_max is None else min(velocity, hard_max),
        "max_accel_mps2": config.max_accel_mps2,
        "robot_hard_max_velocity_mps": hard_max,
        "robot_confirmed_limits": limits is not None,
        "low_battery_v": config.low_battery_v if config.low_battery_v > 0 else None,
        "rail": rail_facts(config, rail),
    }


def firmware_facts(identity: RobotIdentity | None) -> dict[str, Any] | None:
    return None if identity is None else identity.to_json_dict()


def clock_facts() -> dict[str, Any]:
    """The base station's clock now: sync state, NTP offset, the kernel's error bounds."""
    return clock_sync().to_json_dict()


@dataclass
class _Range:
    """Least, mean and greatest of a series of readings, kept without the series."""

    count: int = 0
    total: float = 0.0
    least: float = math.inf
    greatest: float = -math.inf

    def add(self, value: float) -> None:
        self.count += 1
        self.total += value
        self.least = min(self.least, value)
        self.greatest = max(self.greatest, value)

    def to_json_dict(self) -> dict[str, float] | None:
        if not self.count:
            return None
        return {
            "min": round(self.least, 1),
            "mean": round(self.total / self.count, 1),
            "max": round(self.greatest, 1),
        }


@dataclass
class RunLinkTally:
    """The radio link over one run, one exchange at a time (the control loop's tick).

    ``rssi_dbm`` is the base station's RSSI of each telemetry frame, ``robot_rssi_dbm`` the
    robot's of each command; both None for a robot without a radio (the kinematic model).
    """

    run_id: str
    exchanges: int = 0
    answered: int = 0
    rssi: _Range = field(default_factory=_Range)
    robot_rssi: _Range = field(default_factory=_Range)

    def add(self, telemetry: Telemetry | None) -> None:
        self.exchanges += 1
        if telemetry is None:
            return
        self.answered += 1
        rssi = getattr(telemetry, "rssi_dbm", None)
        if isinstance(rssi, int | float) and math.isfinite(rssi):
            self.rssi.add(float(rssi))
        robot_rssi = getattr(telemetry, "robot_rssi_dbm", None)
        if isinstance(robot_rssi, int | float) and math.isfinite(robot_rssi):
            self.robot_rssi.add(float(robot_rssi))

    def to_json_dict(self) -> dict[str, Any]:
        lost = self.exchanges - self.answered
        return {
            "exchanges": self.exchanges,
            "answered": self.answered,
            "lost": lost,
            "loss_pct": round(100.0 * lost / self.exchanges, 2) if self.exchanges else None,
            "rssi_dbm": self.rssi.to_json_dict(),
            "robot_rssi_dbm": self.robot_rssi.to_json_dict(),
        }
