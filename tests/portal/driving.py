"""A robot that drives its program exactly, sampled at the agent's 20 Hz: test data whose
laps, passes and statistics can be worked out by hand."""

from __future__ import annotations

from portal.experiments.analysis import SampleRow

HZ = 20
RAIL_M = 100.0


def drive(
    program: list[tuple[float, str, float]],
    *,
    start_m: float = 10.0,
    battery_v: float = 60.0,
    skip: frozenset[int] = frozenset(),
) -> list[SampleRow]:
    """Ideal samples of a robot driving ``program`` [(speed m/s, cw|ccw, seconds)] at 20 Hz:
    it starts at ``start_m`` and moves exactly as commanded. ``skip`` drops those seqs."""
    rows = []
    position_m = start_m
    seq = 0
    t_s = 0.0
    for index, (speed_mps, direction, duration_s) in enumerate(program):
        for _ in range(round(duration_s * HZ)):
            seq += 1
            if seq not in skip:
                rows.append(
                    SampleRow(
                        seq=seq,
                        t_s=t_s,
                        segment=index,
                        commanded_velocity_mps=speed_mps,
                        velocity_mps=speed_mps,
                        direction=direction,
                        battery_v=battery_v - t_s / 100.0,
                        track_m=position_m % RAIL_M,
                        fix_quality=4 if seq % 4 else 5,
                    )
                )
            step_m = speed_mps / HZ
            position_m += step_m if direction == "cw" else -step_m
            t_s += 1.0 / HZ
    return rows


def segments(program: list[tuple[float, str, float]]) -> list[dict[str, object]]:
    return [{"velocity_mps": v, "direction": d, "duration_s": s} for v, d, s in program]
