"""The tilting GPS antenna joint shared by the base-station support and the robot's branch.

The thesis's GPS supports had "a movable axle that allows obtaining the best GPS cover
angle" (section 3.7.1, figure 3.27; the robot's GPS slot in figure 3.29 has the same). Here:
a fork of two ears carries an M6 axle; the antenna's cradle hangs between the ears on two
lugs. A row of detent holes in the ears, on an arc round the axle like a protractor's marks,
takes an M4 bolt through the matching hole of the cradle's lugs: the tilt is positive, so
wind cannot turn it, and repeatable. Both ears and both lugs are bored, so one long M4 bolt
pins the cradle in double shear. The axle bolt's nut clamps the lugs against nylon washers
for a joint without play.

Frame: the axle is the y axis; at tilt 0 the cradle's platform is parallel to the xy plane
above the axle; a positive tilt turns the cradle about +y. The fork's base surface (the part
the ears stand on) is the plane z = -``axle_height_mm``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cadquery as cq

from cad import hardware
from cad.checks import check_sizes
from cad.geometry import (
    box,
    cylinder,
    fuse,
    polar,
    rounded_box,
    single_solid,
    through_cylinder,
    triangle_rib,
)

# Plastic left between two detent holes; thinner webs tear when the bolt is tightened.
DETENT_WEB_MM = 1.5


@dataclass(frozen=True)
class TiltJoint:
    axle_d_mm: float = hardware.CLEAR_M6_MM
    pin_d_mm: float = hardware.CLEAR_M4_MM
    ear_mm: float = 6.0
    lug_mm: float = 6.0
    washer_mm: float = 1.0  # nylon washer between each lug and its ear
    lug_span_mm: float = 40.0  # outer face to outer face of the two lugs
    detent_radius_mm: float = 24.0
    tilt_max_deg: float = 45.0
    tilt_step_deg: float = 15.0
    margin_mm: float = 4.0  # plastic round the holes at the edges
    axle_height_mm: float = 25.0
    clearance_mm: float = 1.5
    # The cradle's platform, where the antenna sits.
    platform_l_mm: float = 110.0  # across the axle
    platform_w_mm: float = 110.0  # along the axle
    platform_mm: float = 4.0
    # 5/8"-11 UNC, the survey-antenna thread: a bolt or adapter goes through this hole.
    antenna_hole_d_mm: float = 16.5

    def __post_init__(self) -> None:
        check_sizes(self, may_be_zero=("washer_mm", "antenna_hole_d_mm", "tilt_max_deg"))
        if self.tilt_max_deg >= 80:
            raise ValueError("tilt_max_deg must be below 80: the antenna would face the roof")
        if 0 < self.tilt_max_deg < self.tilt_step_deg:
            raise ValueError("tilt_step_deg must not exceed tilt_max_deg")
        chord = 2 * self.detent_radius_mm * math.sin(math.radians(self.tilt_step_deg) / 2)
        if chord < self.pin_d_mm + DETENT_WEB_MM:
            need = (self.pin_d_mm + DETENT_WEB_MM) / (
                2 * math.sin(math.radians(self.tilt_step_deg) / 2)
            )
            raise ValueError(
                f"tilt_step_deg {self.tilt_step_deg} is too fine for detent_radius_mm "
                f"{self.detent_radius_mm}: the holes would run into each other "
                f"(needs detent_radius_mm >= {need:.1f})"
            )
        if self.detent_radius_mm < (self.axle_d_mm + self.pin_d_mm) / 2 + DETENT_WEB_MM:
            raise ValueError("detent_radius_mm puts the detent holes into the axle hole")
        if self.lug_span_mm < 2 * self.lug_mm + 8.0:
            raise ValueError("lug_span_mm leaves no room for the detent nut between the lugs")
        if self.platform_w_mm < self.lug_span_mm:
            raise ValueError("platform_w_mm must be at least lug_span_mm")
        if self.antenna_hole_d_mm > min(self.platform_l_mm, self.platform_w_mm) / 2:
            raise ValueError("antenna_hole_d_mm is too large for the platform")
        if self.axle_height_mm < self.lug_radius_mm + self.clearance_mm:
            raise ValueError("axle_height_mm is too low: the lugs would hit the base")
        if self.lowest_platform_mm() < -self.axle_height_mm + self.clearance_mm:
            raise ValueError(
                f"at tilt_max_deg {self.tilt_max_deg} the platform hits the base: raise "
                f"axle_height_mm (at least {self.min_axle_height_mm():.1f}) or shorten "
                "platform_l_mm"
            )

    @property
    def ear_radius_mm(self) -> float:
        return self.detent_radius_mm + self.pin_d_mm / 2 + self.margin_mm

    @property
    def platform_z_mm(self) -> float:
        """The platform's underside above the axle: always clear of the ears' round tops."""
        return self.ear_radius_mm + self.clearance_mm

    @property
    def lug_radius_mm(self) -> float:
        return max(self.axle_d_mm, self.pin_d_mm) / 2 + self.margin_mm

    @property
    def ear_inner_y_mm(self) -> float:
        return self.lug_span_mm / 2 + self.washer_mm

    @property
    def ear_outer_y_mm(self) -> float:
        return self.ear_inner_y_mm + self.ear_mm

    def detent_angles_deg(self) -> list[float]:
        count = math.floor(self.tilt_max_deg / self.tilt_step_deg + 1e-9)
        return [k * self.tilt_step_deg for k in range(-count, count + 1)]

    def lowest_platform_mm(self) -> float:
        """The lowest point the platform reaches over the tilt range (z, axle at 0)."""
        t = math.radians(self.tilt_max_deg)
        a = self.platform_l_mm / 2
        return -a * math.sin(t) + self.platform_z_mm * math.cos(t)

    def min_axle_height_mm(self) -> float:
        return max(
            self.lug_radius_mm + self.clearance_mm,
            -self.lowest_platform_mm() + self.clearance_mm,
        )

    def swing_radius_mm(self) -> float:
        """How far from the axle any part of the cradle can reach."""
        a = self.platform_l_mm / 2
        return math.hypot(a, self.platform_z_mm + self.platform_mm)


def fork(joint: TiltJoint, base_z: float | None = None) -> cq.Shape:
    """The two ears with their axle and detent holes, standing on z = -axle_height_mm.

    ``base_z`` lets the ears reach a little into the base they are fused to.
    """
    j = joint
    r = j.ear_radius_mm
    z0 = -j.axle_height_mm if base_z is None else base_z
    ears = []
    for sign in (-1, 1):
        y0, y1 = sign * j.ear_inner_y_mm, sign * j.ear_outer_y_mm
        ear = fuse(
            [
                box(-r, min(y0, y1), z0, r, max(y0, y1), 0),
                cylinder((0, min(y0, y1), 0), 2 * r, j.ear_mm, "Y"),
            ]
        )
        # The round top's lower half would poke through a low base.
        below = box(-r - 1, min(y0, y1) - 1, z0 - 2 * r, r + 1, max(y0, y1) + 1, z0)
        ears.append(ear.cut(below))
    span = 2 * j.ear_outer_y_mm + 2
    holes = [through_cylinder((0, 0, 0), j.axle_d_mm, span, "Y")]
    for angle in j.detent_angles_deg():
        # Angle 0 is straight above the axle; positive tilt moves the mark towards +x.
        x, z = polar(j.detent_radius_mm, 90.0 - angle)
        holes.append(through_cylinder((x, 0, z), j.pin_d_mm, span, "Y"))
    return fuse(ears).cut(*holes)


def gussets(joint: TiltJoint, length_mm: float, thickness_mm: float) -> list[cq.Shape]:
    """Ribs on the ears' outer faces, kept below the axle bolt's washer."""
    j = joint
    height = j.axle_height_mm - j.lug_radius_mm - 2.0
    if height <= 2.0:
        return []
    ribs = []
    for sign in (-1, 1):
        y = sign * (j.ear_outer_y_mm - 0.5)
        ribs.append(
            triangle_rib(
                (y, -j.axle_height_mm - 0.01),
                sign * (length_mm + 0.5),
                height,
                "YZ",
                0.0,
                thickness_mm,
            )
        )
    return ribs


def cradle(joint: TiltJoint, tilt_deg: float = 0.0) -> cq.Solid:
    """The antenna's platform on its two lugs, turned to ``tilt_deg`` about the axle."""
    j = joint
    a, b = j.platform_l_mm / 2, j.platform_w_mm / 2
    h = j.platform_z_mm
    plate = rounded_box(-a, -b, h, a, b, h + j.platform_mm, min(8.0, a / 2, b / 2))
    lug_r = j.lug_radius_mm
    pieces: list[cq.Shape] = [plate]
    for sign in (-1, 1):
        y_out = sign * j.lug_span_mm / 2
        y_in = sign * (j.lug_span_mm / 2 - j.lug_mm)
        y0, y1 = min(y_in, y_out), max(y_in, y_out)
        pieces.append(box(-lug_r, y0, 0, lug_r, y1, h + 0.01))
        pieces.append(cylinder((0, y0, 0), 2 * lug_r, j.lug_mm, "Y"))
        # A fillet-like web where lug meets plate, on the inner face: it stiffens the joint
        # against the antenna's leverage and prints as a 45-degree slope.
        web = 4.0
        pieces.append(triangle_rib((y_in, h + 0.01), -sign * web, -web, "YZ", 0.0, 2 * lug_r))
    body = fuse(pieces)
    span = j.lug_span_mm + 2
    cutters = [
        through_cylinder((0, 0, 0), j.axle_d_mm, span, "Y"),
        through_cylinder((0, 0, j.detent_radius_mm), j.pin_d_mm, span, "Y"),
    ]
    if j.antenna_hole_d_mm > 0:
        cutters.append(cylinder((0, 0, h - 1), j.antenna_hole_d_mm, j.platform_mm + 2))
    solid = single_solid(body.cut(*cutters).clean(), "cradle")
    if tilt_deg:
        return solid.rotate(cq.Vector(0, 0, 0), cq.Vector(0, 1, 0), tilt_deg)
    return solid
