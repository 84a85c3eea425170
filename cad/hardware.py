"""Bought parts the models make room for: screws, inserts, connectors, glands, the fan.

Sizes are the standards' or common catalogue values; each says where it comes from. Check the
ones marked "check the part" against the exact part you buy before printing or machining.
"""

from __future__ import annotations

from dataclasses import dataclass

# Clearance holes, ISO 273 "medium" series: a screw passes freely without a sloppy fit.
CLEAR_M3_MM = 3.4
CLEAR_M4_MM = 4.5
CLEAR_M6_MM = 6.6

# Pilot holes for thread-forming screws driven straight into printed plastic (PETG/ASA):
# about 85 % of the nominal diameter bites without splitting a boss. For a machined part,
# tap instead (M2.5 tap drill 2.05 mm, M3 2.5 mm) and use the same positions.
PILOT_M2_5_MM = 2.2
PILOT_M3_MM = 2.6

# Brass heat-set insert M3 x 5.7 mm, the usual size for printed enclosures that are opened
# often: 4.0 mm hole, at least 1.6 mm of plastic around it. Check the part: makers differ.
INSERT_M3_HOLE_MM = 4.0
INSERT_M3_LENGTH_MM = 5.7

# M3 flat (countersunk, ISO 10642) head, about 6 mm across and 90 degrees: sunk at 6.3 mm
# so the head ends flush or just below the lid's top.
CSK_M3_HEAD_MM = 6.3
CSK_ANGLE_DEG = 90.0


@dataclass(frozen=True)
class Bulkhead:
    """A panel connector held by a nut: SMA bulkhead (1/4"-36 UNS thread)."""

    hole_d_mm: float = 6.5  # 6.35 mm thread plus printing/drilling allowance
    nut_af_mm: float = 8.0  # 5/16" hex nut across flats
    # Thread length limits the panel; 4-5 mm is common for SMA bulkheads. Check the part.
    max_panel_mm: float = 5.0
    # How far the rear body and the coax bend need behind the panel.
    rear_mm: float = 12.0

    @property
    def nut_clearance_d_mm(self) -> float:
        # Room for a spanner around the nut, not just the nut's corners.
        return self.nut_af_mm * 1.155 + 3.0


@dataclass(frozen=True)
class Gland:
    """A cable gland M12 x 1.5 (or PG7) with its locknut, for 3-6.5 mm cables. Check the part."""

    hole_d_mm: float = 12.5
    locknut_d_mm: float = 17.0  # across corners of the 15 mm locknut
    inside_mm: float = 8.0  # thread and locknut behind the wall


@dataclass(frozen=True)
class Fan:
    """A 40 x 40 x 10 mm 5 V fan (the common "4010" size), screws on a 32 mm square."""

    size_mm: float = 40.0
    thickness_mm: float = 10.0
    hole_pitch_mm: float = 32.0
    hole_d_mm: float = CLEAR_M3_MM
    bore_d_mm: float = 38.0  # the blades' swept circle


SMA_BULKHEAD = Bulkhead()
M12_GLAND = Gland()
FAN_4010 = Fan()
