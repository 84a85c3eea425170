"""The robot's body on the rail: motor drive, inertia, rolling resistance, braking, battery.

One dimension: the robot moves along the rail, ``velocity_mps`` signed (+ = CW). The model,
from the firmware's outputs inwards:

- **Throttle.** The 490 Hz PWM reaches the motor controller's throttle input through an RC
  filter: a first-order lag (``throttle_time_constant_s``) on ``duty / duty_max``. The 8-bit
  duty is a staircase (one step is 8.333 m/s / 255 = 32.7 mm/s); the filter smooths it.
- **Motor controller.** A speed loop holding the wheel at ``throttle x motor_full_scale_mps``
  in the direction of the direction pin, modelled as an I-P loop (integral on the speed
  error, proportional on the measured speed) tuned critically damped: it tracks the ramp
  without overshoot and rolling resistance leaves no steady-state error. Its force is
  limited (current limit) to ``max_drive_force_n`` forward and ``max_brake_force_n`` braking:
  when the duty falls the motor brakes, but it never drives against the direction pin. Below
  ``throttle_deadband_mps`` the throttle counts as released: the loop only brakes, to rest.
- **E-stop.** With the driver's enable line LOW the controller is off and shorts the motor
  phases (dynamic braking, force proportional to speed, ``short_brake_n_per_mps``).
- **Body.** ``mass_kg`` with rolling resistance ``rolling_resistance x m x g`` against the
  motion (and holding the robot at rest against smaller forces).
- **Wheel slip.** A worn or wet drive wheel loses ``wheel_slip`` of its travel on the rail:
  the controller holds the wheel's speed, the body (and its GPS) moves that share slower, and
  a wheel sensor counts the wheel's turns (``wheel_m``), not the body's travel. 0 by default.
- **Battery.** Five 12 V lead-acid batteries in series: open-circuit voltage linear in the
  state of charge, internal resistance sag with the current drawn (electronics + motor power
  + winding losses; braking energy is dissipated, not recovered), discharge by coulomb count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

G_MPS2: Final = 9.81


@dataclass(frozen=True)
class PhysicsConfig:
    mass_kg: float = 70.0
    rolling_resistance: float = 0.01
    motor_full_scale_mps: float = 8.333  # the thesis: close to 30 km/h unmounted
    throttle_time_constant_s: float = 0.1
    speed_loop_bandwidth_rad_s: float = 8.0
    speed_loop_damping: float = 1.0
    max_drive_force_n: float = 150.0
    max_brake_force_n: float = 150.0
    throttle_deadband_mps: float = 0.02
    short_brake_n_per_mps: float = 140.0
    motor_force_per_amp_n: float = 20.0
    motor_winding_ohm: float = 0.4
    wheel_slip: float = 0.0  # share of the drive wheel's travel lost on the rail (wear)

    @property
    def rolling_force_n(self) -> float:
        return self.rolling_resistance * self.mass_kg * G_MPS2

    @property
    def kp_n_per_mps(self) -> float:
        return 2.0 * self.speed_loop_damping * self.mass_kg * self.speed_loop_bandwidth_rad_s

    @property
    def ki_n_per_m(self) -> float:
        return self.mass_kg * self.speed_loop_bandwidth_rad_s**2

    @property
    def lag_s(self) -> float:
        """How far the body's speed trails a speed ramp: the throttle filter plus the speed
        loop's ramp-following lag (2zeta/wn for the I-P loop)."""
        return self.throttle_time_constant_s + (
            2.0 * self.speed_loop_damping / self.speed_loop_bandwidth_rad_s
        )

    def braking_distance_m(self, speed_mps: float, decel_mps2: float) -> float:
        """Distance from the moment the firmware starts ramping down at ``decel_mps2`` to rest:
        the ramp's v^2/2a plus the lag at the initial speed. An upper bound: rolling
        resistance only shortens it."""
        v = abs(speed_mps)
        return v * v / (2.0 * decel_mps2) + v * self.lag_s

    def stopping_distance_bound_m(
        self, speed_mps: float, decel_mps2: float, reaction_s: float
    ) -> float:
        """Distance covered at ``speed_mps`` for ``reaction_s`` (e.g. the dead-man time) plus
        the braking distance."""
        return abs(speed_mps) * reaction_s + self.braking_distance_m(speed_mps, decel_mps2)

    def e_stop_distance_m(self, speed_mps: float) -> float:
        """Distance to rest with the drive removed (dynamic braking c·v plus rolling
        resistance F): x = (m/c)·v0 - (F/c)·t*, with t* = (m/c)·ln(1 + c·v0/F)."""
        v0 = abs(speed_mps)
        c, f, m = self.short_brake_n_per_mps, self.rolling_force_n, self.mass_kg
        if v0 == 0.0:
            return 0.0
        if f == 0.0:
            return m / c * v0
        t_stop = m / c * math.log1p(c * v0 / f)
        return m / c * v0 - f / c * t_stop

    def e_stop_time_s(self, speed_mps: float) -> float:
        v0 = abs(speed_mps)
        c, f, m = self.short_brake_n_per_mps, self.rolling_force_n, self.mass_kg
        if v0 == 0.0:
            return 0.0
        return m / c * math.log1p(c * v0 / f) if f > 0 else math.inf


@dataclass(frozen=True)
class BatteryConfig:
    batteries: int = 5
    capacity_ah: float = 12.0
    initial_soc: float = 0.7  # 5 x 12.04 V: "about 60 V"
    empty_v: float = 10.5  # one 12 V battery, open circuit, at 0 % charge
    full_v: float = 12.7  # ... and at 100 %
    internal_resistance_ohm: float = 0.12  # the whole string
    idle_current_a: float = 0.1  # Arduino, GPS, radio, controller quiescent
    adc_noise_counts: float = 0.5
    adc_spike_probability: float = 0.005  # motor noise on the divider (thesis figure 3.20)
    adc_spike_v: float = 6.0


class RobotPhysics:
    """State of the body and the battery; :meth:`step` integrates one time step."""

    def __init__(
        self,
        config: PhysicsConfig | None = None,
        battery: BatteryConfig | None = None,
        *,
        odometer_m: float = 0.0,
    ) -> None:
        self.config = config if config is not None else PhysicsConfig()
        self.battery = battery if battery is not None else BatteryConfig()
        self.odometer_m = odometer_m  # unwrapped, signed: + = CW
        self.wheel_m = 0.0  # the drive wheel's travel, signed (slip makes it run ahead)
        self.velocity_mps = 0.0  # signed, + = CW
        self.accel_mps2 = 0.0
        self.throttle_mps = 0.0  # the filtered throttle as a speed setpoint (magnitude)
        self.force_n = 0.0  # motor force, signed along the track
        self.soc = self.battery.initial_soc
        self.current_a = self.battery.idle_current_a
        self._integral_n = 0.0
        c = self.config
        self._kp = c.kp_n_per_mps
        self._ki = c.ki_n_per_m
        self._friction_n = c.rolling_force_n

    @property
    def ocv_v(self) -> float:
        b = self.battery
        return b.batteries * (b.empty_v + (b.full_v - b.empty_v) * max(0.0, min(1.0, self.soc)))

    @property
    def battery_v(self) -> float:
        """Terminal voltage: open-circuit voltage minus the sag of the current drawn."""
        return self.ocv_v - self.current_a * self.battery.internal_resistance_ohm

    def _motor_force(self, w: float, drive_enabled: bool, dt_s: float) -> float:
        """Controller force along the direction pin, given the speed ``w`` along it."""
        c = self.config
        if not drive_enabled:
            self._integral_n = 0.0
            return -c.short_brake_n_per_mps * w
        self._integral_n += self._ki * (self.throttle_mps - w) * dt_s
        unclamped = self._integral_n - self._kp * w
        force = unclamped
        # Throttle released: the loop may still brake (to rest) but never pushes; otherwise its
        # integral, which holds against rolling resistance, would creep the robot along.
        ceiling = 0.0 if self.throttle_mps < c.throttle_deadband_mps else c.max_drive_force_n
        if force > ceiling:
            force = ceiling
        elif force < 0.0:
            if w <= 0.0:  # a controller driving one way cannot pull the other way
                force = 0.0
            elif force < -c.max_brake_force_n:
                force = -c.max_brake_force_n
        if force != unclamped:
            self._integral_n = force + self._kp * w  # anti-windup: hold the integral at the limit
        return force

    def step(
        self, dt_s: float, *, duty: int, duty_max: int, direction_cw: bool, drive_enabled: bool
    ) -> None:
        c = self.config
        sign = 1.0 if direction_cw else -1.0
        target_mps = duty / duty_max * c.motor_full_scale_mps if drive_enabled and duty_max else 0.0
        # Exact discretisation of the RC filter: stable for any dt.
        self.throttle_mps += (target_mps - self.throttle_mps) * (
            1.0 - math.exp(-dt_s / c.throttle_time_constant_s)
        )
        w = self.velocity_mps * sign
        force = self._motor_force(w, drive_enabled, dt_s)
        if w == 0.0 and abs(force) <= self._friction_n:
            w_new = 0.0  # static friction holds
        else:
            friction = -math.copysign(self._friction_n, w if w else force)
            w_new = w + (force + friction) / c.mass_kg * dt_s
            if w * w_new < 0.0:
                w_new = 0.0  # braking and friction stop the robot; they do not reverse it
        new_velocity = w_new * sign
        self.accel_mps2 = (new_velocity - self.velocity_mps) / dt_s
        # Trapezoidal position update: exact for constant acceleration over the step. The
        # speed loop holds the wheel's speed; the body keeps (1 - slip) of the wheel's travel.
        wheel_step_m = 0.5 * (self.velocity_mps + new_velocity) * dt_s
        self.wheel_m += wheel_step_m
        self.odometer_m += wheel_step_m * (1.0 - c.wheel_slip)
        self.velocity_mps = new_velocity
        self.force_n = force * sign
        self._battery_step(dt_s, force, w_new, drive_enabled)

    def _battery_step(self, dt_s: float, force_n: float, w_mps: float, drive_enabled: bool) -> None:
        b, c = self.battery, self.config
        current = b.idle_current_a
        if drive_enabled:
            motor_a = abs(force_n) / c.motor_force_per_amp_n
            power_w = max(0.0, force_n * w_mps) + motor_a * motor_a * c.motor_winding_ohm
            current += power_w / max(self.ocv_v, 1.0)
        self.current_a = current
        self.soc = max(0.0, self.soc - current * dt_s / (b.capacity_ah * 3600.0))
