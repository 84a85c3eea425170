"""The one narrow interface between the agent and a robot.

The manager only ever calls :meth:`Robot.exchange`: one command out, one telemetry frame
back, once per control tick. Today :class:`SimpleSimulatedRobot` answers; later the real
radio link (RFM69 over SPI, or the emulated radio with the firmware core) sits behind the
same method, so nothing above this module changes.
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

# Re-exported: the robot's interface speaks the contract's directions.
from basestation.contract import DIRECTIONS as DIRECTIONS
from basestation.contract import Direction as Direction


@dataclass(frozen=True)
class Command:
    velocity_mps: float  # speed along the rail, never negative; the sign is in ``direction``
    direction: Direction
    estop: bool = False


@dataclass(frozen=True)
class Telemetry:
    velocity_mps: float  # measured speed, never negative
    direction: Direction
    battery_v: float
    track_m: float  # position along the rail, in [0, rail length); cw increases it


@dataclass(frozen=True)
class RobotLimits:
    """What a robot confirmed when the agent sent it its limits (docs/protocol.md §2.4).

    ``hard_max_velocity_mps`` is the maximum compiled into the robot's firmware: no limit
    sent over the radio can go above it. None when the robot's firmware answers with the
    older config frame, which does not carry it.
    """

    max_velocity_mps: float  # applied by the robot
    max_accel_mps2: float  # applied by the robot
    hard_max_velocity_mps: float | None


@dataclass(frozen=True)
class RobotIdentity:
    """What the robot's firmware says of itself when asked (docs/protocol.md §2.6): its build
    identifier and its compiled-in configuration (field names and units as on the wire)."""

    build_id: str
    config: Mapping[str, int] = field(default_factory=dict)
    protocol_version: int = 1

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "build_id": self.build_id,
            "protocol_version": self.protocol_version,
            "config": dict(self.config),
        }


class RobotLinkError(Exception):
    """No telemetry came back for a command (radio timeout, CRC failure, ...)."""


class Robot(Protocol):
    def exchange(self, command: Command, now_s: float) -> Telemetry:
        """Send ``command`` at agent time ``now_s`` (epoch seconds) and return the telemetry
        that answers it. Raises :class:`RobotLinkError` when the robot does not answer."""
        ...


def signed_velocity_mps(velocity_mps: float, direction: Direction) -> float:
    return velocity_mps if direction == "cw" else -velocity_mps


class SimpleSimulatedRobot:
    """A robot on a closed rail with just enough physics for the agent's logic to be tested.

    Velocity follows the command through a rate limiter, so acceleration never exceeds
    ``max_accel_mps2`` and a direction change always passes through zero. The battery sags
    under load and discharges slowly. The velocity reading carries small seeded noise so
    tests are repeatable yet do not depend on exact values.
    """

    NOISE_LIMIT_MPS = 0.01
    FULL_BATTERY_V = 60.0
    EMPTY_BATTERY_V = 48.0
    SAG_V_PER_MPS = 0.4  # internal resistance: drawing current for speed drops the terminal voltage
    IDLE_DISCHARGE_V_PER_S = 2e-5
    MOTION_DISCHARGE_V_PER_M = 2e-4
    # Longer gaps than this between exchanges (agent paused, clock stepped) are not integrated:
    # the real robot would have stopped on its dead-man timer anyway.
    MAX_STEP_S = 1.0

    def __init__(
        self,
        *,
        max_velocity_mps: float,
        max_accel_mps2: float,
        rail_length_m: float,
        seed: int = 0,
        track_m: float = 0.0,
    ) -> None:
        self.max_velocity_mps = max_velocity_mps
        self.max_accel_mps2 = max_accel_mps2
        self.rail_length_m = rail_length_m
        self._rng = random.Random(seed)
        self._velocity_signed_mps = 0.0
        self._direction: Direction = "cw"
        self._track_m = track_m % rail_length_m
        self._charge_v = self.FULL_BATTERY_V
        self._last_now_s: float | None = None

    @property
    def true_velocity_signed_mps(self) -> float:
        """The noise-free velocity (cw positive), for tests and benchmarks."""
        return self._velocity_signed_mps

    def exchange(self, command: Command, now_s: float) -> Telemetry:
        dt_s = 0.0 if self._last_now_s is None else now_s - self._last_now_s
        dt_s = min(max(dt_s, 0.0), self.MAX_STEP_S)
        self._last_now_s = now_s

        # The e-stop latch and its release belong to the firmware (a later piece of work);
        # here an e-stop command just means "stop", like velocity 0.
        target_mps = 0.0
        if not command.estop:
            speed_mps = min(max(command.velocity_mps, 0.0), self.max_velocity_mps)
            target_mps = signed_velocity_mps(speed_mps, command.direction)

        old_mps = self._velocity_signed_mps
        max_step_mps = self.max_accel_mps2 * dt_s
        step_mps = min(max(target_mps - old_mps, -max_step_mps), max_step_mps)
        new_mps = old_mps + step_mps
        if abs(new_mps) < 1e-9:
            new_mps = 0.0
        self._velocity_signed_mps = new_mps
        if new_mps > 0:
            self._direction = "cw"
        elif new_mps < 0:
            self._direction = "ccw"

        # Trapezoidal integration: exact for a constant acceleration within the step.
        moved_m = 0.5 * (old_mps + new_mps) * dt_s
        self._track_m = (self._track_m + moved_m) % self.rail_length_m
        self._charge_v -= self.IDLE_DISCHARGE_V_PER_S * dt_s + self.MOTION_DISCHARGE_V_PER_M * abs(
            moved_m
        )
        self._charge_v = max(self._charge_v, self.EMPTY_BATTERY_V)

        speed_mps = abs(new_mps)
        if speed_mps > 0:
            # A stopped wheel encoder reads exactly zero; a turning one jitters a little.
            noise_mps = self._rng.gauss(0.0, self.NOISE_LIMIT_MPS / 3)
            noise_mps = min(max(noise_mps, -self.NOISE_LIMIT_MPS), self.NOISE_LIMIT_MPS)
            speed_mps = abs(speed_mps + noise_mps)
        battery_v = self._charge_v - self.SAG_V_PER_MPS * abs(new_mps) + self._rng.gauss(0.0, 0.01)
        track_m = self._track_m
        if math.isclose(track_m, self.rail_length_m):
            track_m = 0.0
        return Telemetry(
            velocity_mps=speed_mps,
            direction=self._direction,
            battery_v=battery_v,
            track_m=track_m,
        )
