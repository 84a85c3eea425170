"""GPS fixes as the base station keeps them: quality per sample, position only while fresh.

The robot sends the last position it knows together with the fix quality of the moment
(docs/protocol.md §2.2). A position is used only while the last fix that had one is
younger than ``stale_after_s``: an old position presented as current would put samples at
a place the robot has long left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from basestation.protocol import FixQuality

DEFAULT_STALE_AFTER_S = 2.0  # the robot's own GPS_STALE threshold (docs/protocol.md §2.2)

FIX_QUALITY_NAMES: Final[dict[FixQuality, str]] = {
    FixQuality.NONE: "none",
    FixQuality.GPS: "gps",
    FixQuality.DGPS: "dgps",
    FixQuality.RTK_FIXED: "rtk_fixed",
    FixQuality.RTK_FLOAT: "rtk_float",
}


@dataclass(frozen=True)
class GpsFix:
    """One position report with the agent time (``at_s``) it arrived."""

    lat_deg: float
    lon_deg: float
    quality: FixQuality
    satellites: int
    at_s: float

    @property
    def has_position(self) -> bool:
        return self.quality is not FixQuality.NONE

    @property
    def quality_name(self) -> str:
        return FIX_QUALITY_NAMES[self.quality]

    def age_s(self, now_s: float) -> float:
        return now_s - self.at_s


class GpsTracker:
    """Keeps the last fix and the last fix that had a position."""

    def __init__(self, stale_after_s: float = DEFAULT_STALE_AFTER_S) -> None:
        if not math.isfinite(stale_after_s) or stale_after_s <= 0:
            raise ValueError(f"stale_after_s must be a positive number, got {stale_after_s!r}")
        self.stale_after_s = stale_after_s
        self.last_fix: GpsFix | None = None
        self.last_position_fix: GpsFix | None = None

    def update(
        self,
        *,
        lat_deg: float,
        lon_deg: float,
        quality: FixQuality | int,
        satellites: int,
        now_s: float,
    ) -> GpsFix | None:
        """Record one sample's fix; return the position fix that is current after it.

        Raises ``ValueError`` for a quality outside 0, 1, 2, 4, 5 or a position outside
        ±90°/±180° (the frame decoder already refuses those; this guards other callers).
        """
        fix_quality = FixQuality(quality)
        if not (math.isfinite(lat_deg) and -90.0 <= lat_deg <= 90.0):
            raise ValueError(f"lat_deg {lat_deg!r} outside ±90°")
        if not (math.isfinite(lon_deg) and -180.0 <= lon_deg <= 180.0):
            raise ValueError(f"lon_deg {lon_deg!r} outside ±180°")
        fix = GpsFix(
            lat_deg=lat_deg,
            lon_deg=lon_deg,
            quality=fix_quality,
            satellites=satellites,
            at_s=now_s,
        )
        self.last_fix = fix
        if fix.has_position:
            self.last_position_fix = fix
        return self.current(now_s)

    def current(self, now_s: float) -> GpsFix | None:
        """The last fix with a position if it is not stale at ``now_s``, else ``None``."""
        fix = self.last_position_fix
        if fix is None or fix.age_s(now_s) > self.stale_after_s:
            return None
        return fix

    @property
    def quality(self) -> FixQuality:
        """Fix quality of the latest sample (``NONE`` before any)."""
        return FixQuality.NONE if self.last_fix is None else self.last_fix.quality
