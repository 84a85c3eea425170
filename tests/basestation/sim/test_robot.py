"""The simulated robot: firmware core + physics + GPS + battery + its radio at frame level."""

from __future__ import annotations

import ctypes
import itertools
import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from basestation.protocol import (
    CommandFlag,
    CommandFrame,
    ConfigAckFrame,
    Direction,
    FixQuality,
    TelemetryFrame,
    TelemetryStatus,
    decode_frame,
    encode_command,
)
from basestation.sim.config import GpsConfig, SimConfig
from basestation.sim.gps import DEFAULT_FIX_MODELS, GpsNoise, gga_sentence
from basestation.sim.physics import BatteryConfig, PhysicsConfig
from basestation.sim.robot import SimulatedRobot
from basestation.sim.scenario import Bench
from basestation.telemetry.rail import Rail


def test_the_robot_answers_over_the_air_with_its_position_and_battery() -> None:
    bench = Bench.create()
    bench.drive(3.0, 0.5)
    assert len(bench.telemetry) == 60
    received_s, last = bench.telemetry[-1]
    assert last.echo_seq == bench.seq
    assert last.fix_quality is FixQuality.RTK_FIXED
    assert last.satellites == 18
    assert last.status == TelemetryStatus(0)
    assert abs(last.battery_v - 60.2) < 0.3  # five 12 V batteries at 70 % charge
    # The telemetry's position is the GPS's: at most one fix period plus its latency old.
    rail = bench.robot.config.rail
    gps_track_m = rail.project(last.lat_deg, last.lon_deg).track_m
    assert abs(gps_track_m - bench.robot.track_m) < 0.1 + 0.15 * 0.5
    assert -70 < last.rssi_dbm < -45
    # Answered one airtime + processing after the command: well inside the 50 ms tick.
    assert received_s - (bench.now_s - 0.05) < 0.015


def test_without_a_fix_the_quality_is_none_and_without_sentences_the_gps_is_stale() -> None:
    bench = Bench.create(SimConfig(gps=GpsConfig(fix="none")))
    bench.drive(2.5, 0.0)
    _, last = bench.telemetry[-1]
    assert last.fix_quality is FixQuality.NONE
    assert TelemetryStatus.GPS_STALE not in last.status  # sentences arrive, without a fix
    bench.robot.set_gps_fix("off")
    bench.drive(2.5, 0.0)
    _, last = bench.telemetry[-1]
    assert TelemetryStatus.GPS_STALE in last.status  # no sentence for 2 s
    assert last.fix_quality is FixQuality.NONE


def test_the_battery_sags_under_load_and_discharges() -> None:
    bench = Bench.create()
    bench.advance(1.0)
    rest_v = bench.robot.physics.battery_v
    soc_before = bench.robot.physics.soc
    bench.drive(7.5, 2.0)  # accelerating all along: about 50 W at the end
    assert bench.robot.physics.battery_v < rest_v - 0.05
    assert bench.robot.physics.current_a > 0.5
    assert bench.robot.physics.soc < soc_before


def test_a_low_battery_is_flagged_and_the_median_rejects_spikes() -> None:
    battery = BatteryConfig(initial_soc=0.05, empty_v=10.0, adc_spike_probability=0.2)
    bench = Bench.create(SimConfig(battery=battery))
    bench.drive(1.0, 0.0)
    _, last = bench.telemetry[-1]
    assert TelemetryStatus.LOW_BATTERY in last.status
    # One sample in five is 6 V low, yet the median of seven stays on the true voltage.
    assert abs(last.battery_v - bench.robot.physics.battery_v) < 0.15


def test_a_broadcast_e_stop_latches_without_an_answer() -> None:
    bench = Bench.create()
    bench.drive(4.0, 1.0)
    answers = len(bench.telemetry)
    bench.send(
        encode_command(
            CommandFrame(
                seq=999, velocity_mm_s=0, direction=Direction.CW, flags=CommandFlag.E_STOP,
                to_node=255, from_node=7,
            )
        )
    )  # fmt: skip
    bench.advance(2.0)
    assert bench.robot.e_stop_latched
    assert bench.robot.velocity_mps == 0.0
    assert len(bench.telemetry) == answers


def test_a_wheel_sensor_reports_the_measured_speed() -> None:
    # A coarse sensor (30 mm a pulse, read every 100 ms) counts 3 or 4 pulses at 1 m/s, so it
    # reads 900 or 1200 mm/s, never the ramp's 1000: the telemetry must carry its reading.
    bench = Bench.create(SimConfig(wheel_um_per_pulse=30_000))
    bench.drive(4.0, 1.0)  # up to speed
    from_m, from_s = bench.robot.physics.odometer_m, bench.now_s
    bench.drive(4.0, 1.0)
    cruise = [frame.velocity_mm_s for at_s, frame in bench.telemetry if at_s > from_s + 0.1]
    assert len(cruise) >= 70
    assert set(cruise) == {900, 1200}
    # Counted pulses lose no travel: on average they are the speed the robot really made.
    true_mm_s = 1000 * (bench.robot.physics.odometer_m - from_m) / (bench.now_s - from_s)
    assert abs(sum(cruise) / len(cruise) - true_mm_s) <= 30
    # Without the sensor the firmware reports the speed it applies.
    plain = Bench.create()
    plain.drive(8.0, 1.0)
    assert {frame.velocity_mm_s for _, frame in plain.telemetry[-70:]} == {1000}


def test_a_config_frame_is_answered_with_the_limits_applied() -> None:
    bench = Bench.create()
    bench.send_config(9.0, 5.0)
    assert bench.configs
    answer = bench.configs[-1]
    assert (answer.max_velocity_mm_s, answer.accel_mm_s2) == (4000, 1000)  # hard limits
    assert answer.hard_max_velocity_mm_s == 4000  # and the robot says which


def test_a_robot_built_with_another_hard_maximum_reports_it() -> None:
    bench = Bench.create(SimConfig(firmware={"hard_max_velocity_mm_s": 2500}))
    bench.send_config(3.0, 0.5)
    answer = bench.configs[-1]
    assert (answer.max_velocity_mm_s, answer.hard_max_velocity_mm_s) == (2500, 2500)


def test_the_robot_follows_a_configured_rail_clockwise_whatever_the_file_order() -> None:
    # Listed counter-clockwise (west, south-east, north-east): CW travel still goes clockwise.
    corners = [(40.6340, -8.6600), (40.6339, -8.6598), (40.6341, -8.6598)]
    triangle = Rail.from_mapping({"points": [{"lat": lat, "lon": lon} for lat, lon in corners]})
    bench = Bench.create(SimConfig(rail=triangle, start_track_m=triangle.length_m - 1.0))
    bench.drive(12.0, 2.0)
    robot = bench.robot
    assert robot.physics.odometer_m > triangle.length_m  # went round past the origin
    assert 0.0 <= robot.track_m < triangle.length_m
    _, last = bench.telemetry[-1]
    assert abs(triangle.project(last.lat_deg, last.lon_deg).track_m - robot.track_m) < 0.5
    # Seen from above, the GPS fixes turn clockwise round the triangle's middle: their
    # summed cross products (x east, y north) are negative.
    middle_x_m = sum(triangle.frame.to_xy_m(*c)[0] for c in corners) / 3
    middle_y_m = sum(triangle.frame.to_xy_m(*c)[1] for c in corners) / 3
    fixes = [
        triangle.frame.to_xy_m(f.lat_deg, f.lon_deg) for _, f in bench.telemetry if f.fix_quality
    ]
    assert len(fixes) > 200
    turn_m2 = sum(
        (ax - middle_x_m) * (by - middle_y_m) - (ay - middle_y_m) * (bx - middle_x_m)
        for (ax, ay), (bx, by) in itertools.pairwise(fixes)
    )
    assert turn_m2 < 0


def test_gps_noise_follows_the_fix_model() -> None:
    rng = random.Random(3)
    fixed = GpsNoise(DEFAULT_FIX_MODELS["rtk_fixed"], rng)
    east = [fixed.next(0.1)[0] for _ in range(4000)]
    sigma = math.sqrt(sum(e * e for e in east) / len(east))
    assert abs(sigma - 0.02) < 0.002
    floating = GpsNoise(DEFAULT_FIX_MODELS["rtk_float"], rng)
    walk = [floating.next(0.1)[0] for _ in range(200)]
    steps = [abs(b - a) for a, b in itertools.pairwise(walk)]
    assert max(steps) < 0.3  # correlated: 10 s correlation time, it wanders, never jumps


@settings(max_examples=200, deadline=None)
@given(
    lat=st.floats(min_value=-89.9, max_value=89.9),
    lon=st.floats(min_value=-179.9, max_value=179.9),
    utc=st.floats(min_value=0.0, max_value=86_399.99),
)
def test_gga_sentences_parse_in_the_firmware(
    firmware_library: ctypes.CDLL, lat: float, lon: float, utc: float
) -> None:
    class Fix(ctypes.Structure):
        _fields_ = [("utc_ms", ctypes.c_uint32), ("lat_e7", ctypes.c_int32),
                    ("lon_e7", ctypes.c_int32), ("quality", ctypes.c_uint8),
                    ("satellites", ctypes.c_uint8), ("has_position", ctypes.c_uint8)]  # fmt: skip

    sentence = gga_sentence(
        utc_s_of_day=utc, lat_deg=lat, lon_deg=lon, quality=4, satellites=18, hdop=0.6
    )
    assert len(sentence) <= 100  # the firmware's NMEA buffer
    fix = Fix()
    assert firmware_library.amz_parse_gga(sentence, len(sentence), ctypes.byref(fix)) == 0
    assert abs(fix.lat_e7 - lat * 1e7) <= 1
    assert abs(fix.lon_e7 - lon * 1e7) <= 1
    assert fix.quality == 4


@settings(max_examples=300, deadline=None)
@given(
    frames=st.lists(
        st.binary(max_size=70)
        | st.builds(
            lambda header, body: header + body[: header[0] - 5],
            st.sampled_from(
                [
                    bytes([13, 2, 1, 0, 1, 1]),
                    bytes([11, 2, 1, 0, 1, 3]),
                    bytes([13, 255, 9, 0, 1, 1]),
                ]
            ),
            st.binary(min_size=25, max_size=25),
        ),
        max_size=8,
    )
)
def test_arbitrary_frames_never_crash_the_robot(
    firmware_library: ctypes.CDLL, frames: list[bytes]
) -> None:
    robot = SimulatedRobot(library=firmware_library)
    try:
        for frame in frames:
            reply = robot.handle_frame(frame, rssi_dbm=-300.0)  # RSSI is clamped to an int8
            if reply:
                assert isinstance(decode_frame(reply), TelemetryFrame | ConfigAckFrame)
            robot.step(0.013)
        assert math.isfinite(robot.velocity_mps)
        assert abs(robot.velocity_mps) <= 4.0 + 0.02  # never beyond the hard limit
    finally:
        robot.close()


def test_a_long_pause_at_rest_is_skipped_not_simulated_tick_by_tick() -> None:
    bench = Bench.create(trace_interval_s=None)
    bench.drive(2.0, 0.0)
    soc = bench.robot.physics.soc
    bench.advance(3600.0)  # an hour in one step: the first access after a pause
    assert bench.robot.time_s == pytest.approx(bench.now_s, abs=0.001)
    idle_drain = bench.robot.config.battery.idle_current_a / bench.robot.config.battery.capacity_ah
    assert soc - bench.robot.physics.soc == pytest.approx(idle_drain, rel=0.01)
    bench.drive(0.2, 0.0)
    _, last = bench.telemetry[-1]
    assert last.status & TelemetryStatus.GPS_STALE == 0  # the last second was simulated
    assert last.robot_clock_ms == pytest.approx((bench.now_s - bench.robot.start_s) * 1000, abs=60)


def test_a_slipping_wheel_turns_further_than_the_robot_moves_and_its_sensor_counts_the_wheel():
    """Wear: with ``wheel_slip`` the speed loop holds the wheel's speed, the body (and its
    GPS) keeps only (1 - slip) of the wheel's travel, and a wheel sensor reports the wheel."""
    slip = 0.2
    bench = Bench.create(SimConfig(physics=PhysicsConfig(wheel_slip=slip), wheel_um_per_pulse=1000))
    physics = bench.robot.physics
    bench.drive(4.0, 1.0)  # up to speed
    from_m, from_wheel_m, from_s = physics.odometer_m, physics.wheel_m, bench.now_s
    bench.drive(4.0, 1.0)
    assert physics.odometer_m - from_m == pytest.approx(
        (1 - slip) * (physics.wheel_m - from_wheel_m)
    )
    # The wheel ran at the commanded metre a second; the robot made 0.8 of it.
    wheel_mps = (physics.wheel_m - from_wheel_m) / (bench.now_s - from_s)
    assert wheel_mps == pytest.approx(1.0, abs=0.02)
    cruise = [frame.velocity_mm_s for at_s, frame in bench.telemetry if at_s > from_s + 0.1]
    assert sum(cruise) / len(cruise) == pytest.approx(1000, abs=20)  # the sensor: the wheel's
