"""The robot's antenna branch: one arm off the frame carrying all three antennas.

The thesis (section 3.7.2, figure 3.29) made "a branch with adapted slots to each antenna,
the GPS slot with a mobile axis like the one from the BS". Here:

- a stem plate bolts to an upright of the robot's metal frame through two vertical slots
  (M6), so the arm's height can be set on the frame;
- the arm is a channel (top plate, two side ribs, open below): stiff against the rail's
  vibration, and the antennas' coax runs inside it, out of the weather and the wheels' way;
- the radio (433 MHz) and Bluetooth antennas screw onto SMA bulkheads through the top plate,
  upright; the GPS antenna sits on a tilting cradle at the arm's tip (``cad.tilt``), far
  enough from the whips that the cradle cannot touch them at any tilt.

Frame: the stem's face against the frame is x = 0, the arm runs along +x, z = 0 is the
stem's bottom; the tilt axle is parallel to y.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cadquery as cq

from cad import hardware
from cad.checks import check_sizes
from cad.geometry import box, cut, cylinder, fuse, single_solid, slot, triangle_rib
from cad.tilt import TiltJoint, cradle, fork


def _robot_joint() -> TiltJoint:
    # A smaller cradle than the base station's: the rover's patch antenna, less wind load.
    return TiltJoint(
        lug_span_mm=28.0,
        platform_l_mm=70.0,
        platform_w_mm=70.0,
        axle_height_mm=12.0,
        tilt_max_deg=30.0,
    )


@dataclass(frozen=True)
class AntennaBranchParams:
    joint: TiltJoint = field(default_factory=_robot_joint)
    antennas: tuple[str, ...] = ("radio 433 MHz", "bluetooth")
    bulkhead: hardware.Bulkhead = hardware.SMA_BULKHEAD
    stem_w_mm: float = 44.0
    stem_h_mm: float = 70.0
    stem_mm: float = 6.0
    stem_slot_w_mm: float = hardware.CLEAR_M6_MM
    stem_slot_len_mm: float = 24.0
    arm_l_mm: float = 190.0
    arm_w_mm: float = 44.0
    arm_mm: float = 4.0  # the top plate: within the SMA bulkhead's panel limit
    rib_mm: float = 3.0
    rib_h_mm: float = 16.0
    first_antenna_mm: float = 30.0  # from the stem's face
    antenna_pitch_mm: float = 45.0
    gusset_mm: float = 40.0  # the brace under the arm, along the stem and along the arm

    def __post_init__(self) -> None:
        check_sizes(self)
        if self.arm_mm > self.bulkhead.max_panel_mm:
            raise ValueError(
                f"arm_mm ({self.arm_mm}) is thicker than the bulkhead's "
                f"{self.bulkhead.max_panel_mm} mm panel limit"
            )
        inner = self.arm_w_mm - 2 * self.rib_mm
        if inner < self.bulkhead.nut_clearance_d_mm:
            raise ValueError("arm_w_mm leaves no room for the bulkhead nuts between the ribs")
        if self.arm_w_mm < 2 * self.joint.ear_outer_y_mm:
            raise ValueError("arm_w_mm is narrower than the GPS fork")
        if self.stem_w_mm < 2 * self.stem_slot_w_mm + 12.0:
            raise ValueError("stem_w_mm leaves too little plastic beside the two slots")
        if self.stem_slot_len_mm > self.stem_h_mm - self.rib_h_mm - 12.0:
            raise ValueError("stem_slot_len_mm does not fit below the arm")
        if self.rib_h_mm <= self.arm_mm:
            raise ValueError("rib_h_mm must be taller than arm_mm")
        if self.first_antenna_mm < self.stem_mm + self.bulkhead.nut_clearance_d_mm / 2:
            raise ValueError("first_antenna_mm puts the first bulkhead into the stem")
        if self.antennas and self.antenna_pitch_mm < self.bulkhead.nut_clearance_d_mm + 2.0:
            raise ValueError("antenna_pitch_mm is too small for a spanner on the nuts")
        if self.gusset_mm >= self.stem_h_mm:
            raise ValueError("gusset_mm must be shorter than stem_h_mm")
        reach = self.joint.swing_radius_mm() + self.bulkhead.nut_clearance_d_mm / 2
        if self.antennas and self.antenna_xs_mm()[-1] > self.axle_x_mm - reach:
            raise ValueError(
                "the GPS cradle would swing into the last antenna: lengthen arm_l_mm or "
                "reduce antenna_pitch_mm"
            )

    @property
    def axle_x_mm(self) -> float:
        return self.arm_l_mm - self.joint.ear_radius_mm

    @property
    def arm_top_mm(self) -> float:
        return self.stem_h_mm

    @property
    def axle_z_mm(self) -> float:
        return self.arm_top_mm + self.joint.axle_height_mm

    def antenna_xs_mm(self) -> list[float]:
        return [
            self.first_antenna_mm + i * self.antenna_pitch_mm for i in range(len(self.antennas))
        ]


@dataclass(frozen=True)
class AntennaBranch:
    params: AntennaBranchParams
    branch: cq.Solid
    cradle: cq.Solid

    def parts(self) -> dict[str, cq.Solid]:
        return {"branch": self.branch, "cradle": self.cradle}

    def cradle_at(self, tilt_deg: float) -> cq.Shape:
        """The cradle on the branch's axle at ``tilt_deg``."""
        p = self.params
        return cradle(p.joint, tilt_deg).translate(cq.Vector(p.axle_x_mm, 0, p.axle_z_mm))

    def exploded(self) -> cq.Shape:
        return cq.Compound.makeCompound([self.branch, self.cradle_at(0.0)])


def build(params: AntennaBranchParams | None = None) -> AntennaBranch:
    p = params or AntennaBranchParams()
    j = p.joint
    half_w = p.arm_w_mm / 2
    top = p.arm_top_mm
    stem = box(0, -p.stem_w_mm / 2, 0, p.stem_mm, p.stem_w_mm / 2, top)
    plate = box(0, -half_w, top - p.arm_mm, p.arm_l_mm, half_w, top)
    pieces = [stem, plate]
    for sign in (-1, 1):
        y = sign * (half_w - p.rib_mm / 2)
        pieces.append(box(0, y - p.rib_mm / 2, top - p.rib_h_mm, p.arm_l_mm, y + p.rib_mm / 2, top))
        # The brace from the stem to the ribs' underside takes the arm's bending moment
        # into the frame; at 45 degrees it prints without support.
        pieces.append(
            triangle_rib(
                (p.stem_mm - 0.5, top - p.rib_h_mm + 0.01),
                p.gusset_mm,
                -p.gusset_mm,
                "XZ",
                y,
                p.rib_mm,
            )
        )
    fork_solid = fork(j, base_z=-j.axle_height_mm - 0.5).translate(
        cq.Vector(p.axle_x_mm, 0, p.axle_z_mm)
    )
    pieces.append(fork_solid)
    body = fuse(pieces)

    cutters = [
        cylinder((x, 0, top - p.arm_mm - 1), p.bulkhead.hole_d_mm, p.arm_mm + 2)
        for x in p.antenna_xs_mm()
    ]
    slot_z = (top - p.rib_h_mm) / 2
    for sign in (-1, 1):
        cutters.append(
            slot(
                (p.stem_mm / 2, sign * p.stem_w_mm / 4, slot_z),
                p.stem_slot_len_mm,
                p.stem_slot_w_mm,
                p.stem_mm + 2,
                "X",
                "Z",
            )
        )
    branch = single_solid(cut(body, cutters), "antenna_branch branch")
    return AntennaBranch(params=p, branch=branch, cradle=cradle(j))
