"""``python -m basestation.sim.report``: the thesis's stop and velocity tests (chapter 4),
redone on the simulator; prints the Markdown tables of docs/simulator.md.

Every run is deterministic (fake clock, seeded noise): the same command prints the same
numbers on any machine.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import replace

from basestation.sim.config import SimConfig
from basestation.sim.scenario import DUTY_STEP_MPS, StopResult, stop_test, velocity_test

STOP_SPEEDS_MPS = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0)
VELOCITY_SPEEDS_MPS = (0.5, 1.0, 1.5, 2.0)
FIXES = ("rtk_fixed", "rtk_float", "gps")


def stop_table(speeds: Sequence[float], config: SimConfig) -> list[str]:
    lines = [
        "| commanded (m/s) | speed at stop (m/s) "
        "| link cut: distance (m) | bound (m) | time (s) "
        "| command 0: distance (m) | bound (m) | time (s) "
        "| e-stop: distance (m) | model (m) | time (s) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for speed in speeds:
        runs: dict[str, StopResult] = {
            kind: stop_test(kind, speed, config=config)
            for kind in ("link_cut", "commanded", "e_stop")
        }
        cut, cmd, est = runs["link_cut"], runs["commanded"], runs["e_stop"]
        lines.append(
            f"| {speed:.1f} | {cut.speed_at_stop_mps:.3f} "
            f"| {cut.distance_m:.2f} | {cut.bound_m:.2f} | {cut.time_s:.2f} "
            f"| {cmd.distance_m:.2f} | {cmd.bound_m:.2f} | {cmd.time_s:.2f} "
            f"| {est.distance_m:.2f} | {est.bound_m:.2f} | {est.time_s:.2f} |"
        )
    return lines


def velocity_table(
    fixes: Sequence[str], speeds: Sequence[float], config: SimConfig, hold_s: float
) -> list[str]:
    lines = [
        "| fix | commanded (m/s) | robot-reported (m/s) | GPS-derived (m/s) | true (m/s) "
        "| GPS - reported (m/s) | GPS - true (m/s) | sigma, model (m/s) "
        "| 1 s GPS speed sigma (m/s) | abs(GPS - true) / sigma | within noise of reported |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for fix in fixes:
        for speed in speeds:
            r = velocity_test(fix, speed, config=config, hold_s=hold_s)
            # Within noise: 3 sigma of the GPS speed, plus half a PWM duty step for the robot
            # reporting its ramp's speed rather than the speed its 8-bit duty produces.
            agrees = abs(r.gps_minus_reported_mps) <= 3 * r.gps_sigma_mps + DUTY_STEP_MPS / 2
            lines.append(
                f"| {fix} | {speed:.1f} | {r.reported_mps:.4f} | {r.gps_mps:.4f} "
                f"| {r.true_mps:.4f} | {r.gps_minus_reported_mps:+.4f} "
                f"| {r.gps_minus_true_mps:+.4f} | {r.gps_sigma_mps:.4f} "
                f"| {r.window_sigma_mps:.3f} | {abs(r.gps_minus_true_mps) / r.gps_sigma_mps:.1f} "
                f"| {'yes' if agrees else 'NO'} |"
            )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m basestation.sim.report", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="two speeds, RTK fixed only")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--hold-s", type=float, default=20.0, help="steady-speed hold")
    args = parser.parse_args(argv)
    config = replace(SimConfig(), seed=args.seed)
    stop_speeds = (1.0, 2.0) if args.quick else STOP_SPEEDS_MPS
    speeds = (1.0, 2.0) if args.quick else VELOCITY_SPEEDS_MPS
    fixes = ("rtk_fixed",) if args.quick else FIXES
    hold_s = min(args.hold_s, 10.0) if args.quick else args.hold_s
    out = [
        f"Simulator report (seed {args.seed}; default robot, rail and firmware limits: "
        "max 2.0 m/s raised by a config frame where needed, ramp 0.25 m/s^2, "
        "dead-man 500 ms, stop deceleration 0.5 m/s^2)",
        "",
        "## Stop distance against velocity",
        "",
        *stop_table(stop_speeds, config),
        "",
        f"## GPS-derived against robot-reported velocity ({hold_s:.0f} s hold)",
        "",
        *velocity_table(fixes, speeds, config, hold_s),
        "",
    ]
    sys.stdout.write("\n".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
