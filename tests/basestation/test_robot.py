"""The simple simulated robot's physics."""

from __future__ import annotations

import itertools

import pytest

from basestation.robot import Command, SimpleSimulatedRobot

PERIOD_S = 0.05


def _robot(seed: int = 0) -> SimpleSimulatedRobot:
    return SimpleSimulatedRobot(
        max_velocity_mps=2.0, max_accel_mps2=1.0, rail_length_m=120.0, seed=seed
    )


def test_it_ramps_to_the_command_at_the_acceleration_limit() -> None:
    robot = _robot()
    command = Command(velocity_mps=1.0, direction="cw")
    speeds = [robot.exchange(command, k * PERIOD_S).velocity_mps for k in range(40)]
    assert speeds[0] == 0.0
    assert speeds[10] == pytest.approx(0.5, abs=0.011)
    assert speeds[-1] == pytest.approx(1.0, abs=0.011)


def test_it_never_exceeds_its_maximum_velocity() -> None:
    robot = _robot()
    command = Command(velocity_mps=5.0, direction="ccw")
    for k in range(100):
        robot.exchange(command, k * PERIOD_S)
    assert robot.true_velocity_signed_mps == -2.0


def test_it_wraps_along_the_closed_rail_both_ways() -> None:
    robot = SimpleSimulatedRobot(
        max_velocity_mps=2.0, max_accel_mps2=100.0, rail_length_m=10.0, seed=0
    )
    positions = [
        robot.exchange(Command(velocity_mps=2.0, direction="cw"), k * PERIOD_S).track_m
        for k in range(200)
    ]
    assert all(0.0 <= p < 10.0 for p in positions)
    assert any(b < a for a, b in itertools.pairwise(positions))  # wrapped
    start = positions[-1]
    back = [
        robot.exchange(Command(velocity_mps=2.0, direction="ccw"), (200 + k) * PERIOD_S).track_m
        for k in range(20)
    ]
    assert back[-1] < start or back[-1] > 9.0
    assert all(0.0 <= p < 10.0 for p in back)


def test_it_keeps_velocity_noise_within_a_centimetre_per_second() -> None:
    robot = _robot(seed=7)
    command = Command(velocity_mps=0.7, direction="cw")
    for k in range(2000):
        telemetry = robot.exchange(command, k * PERIOD_S)
        if k > 20:
            assert abs(telemetry.velocity_mps - 0.7) <= 0.01 + 1e-12


def test_it_sags_the_battery_with_speed_and_discharges_slowly() -> None:
    robot = _robot()
    idle = robot.exchange(Command(velocity_mps=0.0, direction="cw"), 0.0).battery_v
    assert idle == pytest.approx(60.0, abs=0.1)
    moving = [
        robot.exchange(Command(velocity_mps=2.0, direction="cw"), k * PERIOD_S).battery_v
        for k in range(1, 200)
    ]
    assert moving[-1] < idle - 0.5  # 0.4 V/(m/s) sag at 2 m/s
    for k in range(200, 400):
        rested = robot.exchange(Command(velocity_mps=0.0, direction="cw"), k * PERIOD_S)
    assert rested.battery_v < idle
    assert rested.battery_v > 59.0


def test_it_is_repeatable_with_the_same_seed() -> None:
    def trace(seed: int) -> list[float]:
        robot = _robot(seed)
        command = Command(velocity_mps=0.5, direction="cw")
        return [robot.exchange(command, k * PERIOD_S).velocity_mps for k in range(50)]

    assert trace(3) == trace(3)
    assert trace(3) != trace(4)


def test_it_treats_an_estop_as_a_stop_command() -> None:
    robot = _robot()
    for k in range(30):
        robot.exchange(Command(velocity_mps=1.0, direction="cw"), k * PERIOD_S)
    for k in range(30, 80):
        robot.exchange(Command(velocity_mps=1.0, direction="cw", estop=True), k * PERIOD_S)
    assert robot.true_velocity_signed_mps == 0.0
