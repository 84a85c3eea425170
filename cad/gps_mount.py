"""Base-station GPS antenna support: a base plate, a tilting fork and the antenna's cradle.

The NS-HP-GL base receiver needs the clearest sky the roof offers; the fork's detent holes
set the antenna straight up or tipped away from a nearby wall or mast in steps of
``tilt_step_deg`` (thesis section 3.7.1, figure 3.27). The base plate's slots take M6 screws
or anchors into a parapet, a shelf or a plate on a mast; they are slots so that the plate can
be squared to the building after drilling.

Frame: axle on the y axis at z = 0 (see ``cad.tilt``); the base plate's underside is the
lowest point.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cadquery as cq

from cad import hardware
from cad.checks import check_sizes
from cad.geometry import cut, fuse, rounded_box, single_solid, slot
from cad.tilt import TiltJoint, cradle, fork, gussets


@dataclass(frozen=True)
class GpsMountParams:
    joint: TiltJoint = field(default_factory=TiltJoint)
    base_l_mm: float = 110.0  # across the axle
    base_mm: float = 6.0
    gusset_mm: float = 16.0  # how far the ribs reach out from the ears
    rib_mm: float = 5.0
    corner_radius_mm: float = 6.0
    slot_w_mm: float = hardware.CLEAR_M6_MM
    slot_len_mm: float = 16.0
    edge_mm: float = 10.0  # slot centre to the plate's edge

    def __post_init__(self) -> None:
        check_sizes(self, may_be_zero=("corner_radius_mm",))
        if self.slot_len_mm < self.slot_w_mm:
            raise ValueError("slot_len_mm must be at least slot_w_mm")
        if self.edge_mm < self.slot_w_mm:
            raise ValueError("edge_mm leaves less plastic beside the slots than their width")
        ear_r = self.joint.ear_radius_mm
        if self.base_l_mm / 2 - self.edge_mm - self.slot_w_mm / 2 < ear_r + 2.0:
            raise ValueError(
                f"base_l_mm is too short: the screw slots would run under the ears "
                f"(needs at least {2 * (ear_r + 2.0 + self.edge_mm + self.slot_w_mm / 2):.1f})"
            )
        if 2 * (self.edge_mm + self.slot_len_mm) - self.slot_w_mm > self.base_w_mm - 4.0:
            raise ValueError("slot_len_mm is too long for the base plate's width")

    @property
    def base_w_mm(self) -> float:
        """Along the axle: the ears and their ribs, no more."""
        return 2 * (self.joint.ear_outer_y_mm + self.gusset_mm)


@dataclass(frozen=True)
class GpsMount:
    params: GpsMountParams
    bracket: cq.Solid
    cradle: cq.Solid

    def parts(self) -> dict[str, cq.Solid]:
        return {"bracket": self.bracket, "cradle": self.cradle}

    def cradle_at(self, tilt_deg: float) -> cq.Solid:
        return cradle(self.params.joint, tilt_deg)

    def exploded(self) -> cq.Shape:
        angle = self.params.joint.detent_angles_deg()[-1] / 2
        tilt = min(self.params.joint.detent_angles_deg(), key=lambda a: abs(a - angle))
        return cq.Compound.makeCompound([self.bracket, self.cradle_at(tilt)])


def build(params: GpsMountParams | None = None) -> GpsMount:
    p = params or GpsMountParams()
    j = p.joint
    z_top = -j.axle_height_mm
    a, b = p.base_l_mm / 2, p.base_w_mm / 2
    plate = rounded_box(-a, -b, z_top - p.base_mm, a, b, z_top, p.corner_radius_mm)
    body = fuse([plate, fork(j, base_z=z_top - 0.5), *gussets(j, p.gusset_mm, p.rib_mm)])
    # Four slots along the axle, their outer ends ``edge_mm`` from the plate's edges.
    slot_y = b - p.edge_mm + p.slot_w_mm / 2 - p.slot_len_mm / 2
    slots = [
        slot(
            (sx * (a - p.edge_mm), sy * slot_y, z_top - p.base_mm / 2),
            p.slot_len_mm,
            p.slot_w_mm,
            p.base_mm + 2,
            "Z",
            "Y",
        )
        for sx in (-1, 1)
        for sy in (-1, 1)
    ]
    bracket = single_solid(cut(body, slots), "gps_mount bracket")
    return GpsMount(params=p, bracket=bracket, cradle=cradle(j))
