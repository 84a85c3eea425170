"""GPS fixes: quality per sample, position only while fresh."""

from __future__ import annotations

import pytest

from basestation.protocol import FixQuality
from basestation.telemetry import FIX_QUALITY_NAMES, GpsTracker

LAT, LON = 40.6343628, -8.660015


def test_it_keeps_the_quality_of_every_sample() -> None:
    gps = GpsTracker()
    for k, quality in enumerate([4, 5, 2, 1, 0]):
        gps.update(lat_deg=LAT, lon_deg=LON, quality=quality, satellites=9, now_s=k * 0.05)
        assert gps.quality == FixQuality(quality)
        assert gps.last_fix is not None
        assert gps.last_fix.quality_name == FIX_QUALITY_NAMES[FixQuality(quality)]
    assert [FIX_QUALITY_NAMES[q] for q in FixQuality] == [
        "none",
        "gps",
        "dgps",
        "rtk_fixed",
        "rtk_float",
    ]


def test_a_position_is_current_until_it_is_older_than_the_stale_time() -> None:
    gps = GpsTracker(stale_after_s=2.0)
    assert gps.current(0.0) is None
    fix = gps.update(lat_deg=LAT, lon_deg=LON, quality=4, satellites=12, now_s=10.0)
    assert fix is not None
    assert fix.has_position
    # Samples without a fix do not erase the last position, they only let it age.
    assert gps.update(lat_deg=0.0, lon_deg=0.0, quality=0, satellites=0, now_s=11.0) == fix
    assert gps.quality is FixQuality.NONE
    assert gps.current(12.0) == fix
    assert gps.current(12.001) is None  # stale: position unknown
    fresh = gps.update(lat_deg=LAT, lon_deg=LON, quality=5, satellites=7, now_s=13.0)
    assert fresh is not None
    assert fresh.quality is FixQuality.RTK_FLOAT
    assert fresh.age_s(13.5) == pytest.approx(0.5)


@pytest.mark.parametrize(
    ("lat", "lon", "quality"),
    [(LAT, LON, 3), (LAT, LON, 6), (91.0, LON, 4), (LAT, -180.5, 4), (float("nan"), LON, 1)],
)
def test_it_refuses_impossible_fixes(lat: float, lon: float, quality: int) -> None:
    gps = GpsTracker()
    with pytest.raises(ValueError):  # noqa: PT011 -- FixQuality and range errors alike
        gps.update(lat_deg=lat, lon_deg=lon, quality=quality, satellites=5, now_s=0.0)
    assert gps.last_fix is None


def test_the_stale_time_must_be_positive() -> None:
    with pytest.raises(ValueError, match="stale_after_s"):
        GpsTracker(stale_after_s=0.0)
