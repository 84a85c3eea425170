"""The robot's RTK GPS receiver: NMEA GGA sentences at 10 Hz with noise per fix state.

Position noise is a first-order Gauss-Markov process per axis (east, north): standard
deviation ``sigma_m`` and correlation time ``correlation_s`` (0: white). RTK fixed noise is
centimetres and uncorrelated at 10 Hz; float and plain GPS errors wander slowly (multipath,
atmosphere), which is why their short-window velocity is better than their position.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass
from typing import Final

#: GGA quality field per fix state (only these reach the telemetry's fix_quality).
FIX_QUALITY: Final[dict[str, int]] = {
    "none": 0,
    "gps": 1,
    "dgps": 2,
    "rtk_fixed": 4,
    "rtk_float": 5,
}


@dataclass(frozen=True)
class FixModel:
    quality: int
    sigma_m: float  # per axis
    correlation_s: float
    satellites: int
    hdop: float


DEFAULT_FIX_MODELS: Final[dict[str, FixModel]] = {
    "rtk_fixed": FixModel(4, 0.02, 0.0, 18, 0.6),
    "rtk_float": FixModel(5, 0.3, 10.0, 16, 0.7),
    "dgps": FixModel(2, 0.7, 20.0, 12, 0.9),
    "gps": FixModel(1, 2.0, 30.0, 9, 1.3),
    "none": FixModel(0, 0.0, 0.0, 3, 99.9),
    "off": FixModel(0, 0.0, 0.0, 0, 99.9),
}


def nmea_checksum(body: str) -> str:
    value = 0
    for char in body.encode("ascii"):
        value ^= char
    return f"{value:02X}"


def _angle(value_deg: float, degree_digits: int) -> str:
    """(d)ddmm.mmmmmmm: seven decimals of minutes, what the firmware reads (1e-7 degree)."""
    value = abs(value_deg)
    degrees = int(value)
    minutes = (value - degrees) * 60.0
    text = f"{minutes:010.7f}"
    if text.startswith("60"):  # rounding reached the next degree
        degrees += 1
        text = f"{0.0:010.7f}"
    return f"{degrees:0{degree_digits}d}{text}"


def gga_sentence(
    *,
    utc_s_of_day: float,
    lat_deg: float | None,
    lon_deg: float | None,
    quality: int,
    satellites: int,
    hdop: float,
    altitude_m: float = 30.0,
    geoid_m: float = 51.3,
    differential_age_s: float | None = None,
) -> bytes:
    """One ``$GNGGA`` sentence with its checksum and CRLF (under the firmware's 100 bytes)."""
    seconds = utc_s_of_day % 86400.0
    hh = int(seconds // 3600)
    mm = int(seconds % 3600 // 60)
    ss = seconds % 60
    time_field = f"{hh:02d}{mm:02d}{ss:05.2f}"
    if time_field.endswith("60.00"):  # rounding: keep the field valid
        time_field = f"{hh:02d}{mm:02d}59.99"
    if lat_deg is None or lon_deg is None:
        position = ",,,"
    else:
        position = (
            f"{_angle(lat_deg, 2)},{'N' if lat_deg >= 0 else 'S'},"
            f"{_angle(lon_deg, 3)},{'E' if lon_deg >= 0 else 'W'}"
        )
    age = "" if differential_age_s is None else f"{differential_age_s:.1f}"
    station = "" if differential_age_s is None else "0000"
    altitude = f"{altitude_m:.1f},M,{geoid_m:.1f},M" if quality else ",,,"
    body = (
        f"GNGGA,{time_field},{position},{quality},{satellites:02d},{hdop:.1f},"
        f"{altitude},{age},{station}"
    )
    return f"${body}*{nmea_checksum(body)}\r\n".encode("ascii")


class GpsNoise:
    """Gauss-Markov position error for one fix state, seeded."""

    def __init__(self, model: FixModel, rng: random.Random) -> None:
        self.model = model
        self._rng = rng
        self.east_m = rng.gauss(0.0, model.sigma_m)
        self.north_m = rng.gauss(0.0, model.sigma_m)

    def next(self, dt_s: float) -> tuple[float, float]:
        m = self.model
        phi = math.exp(-dt_s / m.correlation_s) if m.correlation_s > 0 else 0.0
        spread = m.sigma_m * math.sqrt(1.0 - phi * phi)
        self.east_m = phi * self.east_m + self._rng.gauss(0.0, spread)
        self.north_m = phi * self.north_m + self._rng.gauss(0.0, spread)
        return self.east_m, self.north_m


def velocity_noise_mps(model: FixModel, window_s: float) -> float:
    """Standard deviation of a speed taken as (position difference over ``window_s``) /
    ``window_s`` along one axis: sigma·sqrt(2(1 - e^(-W/tau)))/W (white noise: sigma·sqrt(2)/W)."""
    if model.correlation_s > 0:
        decorrelated = 1.0 - math.exp(-window_s / model.correlation_s)
    else:
        decorrelated = 1.0
    return model.sigma_m * math.sqrt(2.0 * decorrelated) / window_s
