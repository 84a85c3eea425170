"""The box both cases share: a base with walls, corner pillars for the lid screws, a lid plate.

Frame: the cavity's x-/y- inner corner is the origin, the base's bottom face is z = 0, the
floor's top face is z = ``floor_mm`` and the rim (where the lid sits) is z = ``rim_mm``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import cadquery as cq

from cad.geometry import box, cone, cylinder, rounded_box

# Thinnest plastic left between a hole and a surface: two perimeters of a 0.4 mm nozzle plus
# margin; thinner webs crack when a screw is driven.
MIN_WEB_MM = 1.0


class CaseParams(Protocol):
    """The parameters every case names the same way."""

    @property
    def wall_mm(self) -> float: ...
    @property
    def floor_mm(self) -> float: ...
    @property
    def corner_radius_mm(self) -> float: ...
    @property
    def pillar_d_mm(self) -> float: ...
    @property
    def lid_screw_depth_mm(self) -> float: ...


def case_shell(
    p: CaseParams,
    *,
    inner_l_mm: float,
    inner_w_mm: float,
    inner_h_mm: float,
    pillar_hole: tuple[float, str],
) -> Shell:
    """A case's shell from its parameters, checked; ``pillar_hole`` is the lid screw hole's
    diameter and the name of the case's parameter for it (a pilot hole or an insert's)."""
    hole_d_mm, hole_name = pillar_hole
    shell = Shell(
        inner_l_mm=inner_l_mm,
        inner_w_mm=inner_w_mm,
        inner_h_mm=inner_h_mm,
        wall_mm=p.wall_mm,
        floor_mm=p.floor_mm,
        corner_radius_mm=p.corner_radius_mm,
        pillar_d_mm=p.pillar_d_mm,
        pillar_hole_d_mm=hole_d_mm,
        pillar_hole_depth_mm=p.lid_screw_depth_mm,
    )
    shell.validate({"pillar_hole_d_mm": hole_name, "pillar_hole_depth_mm": "lid_screw_depth_mm"})
    return shell


@dataclass(frozen=True)
class Shell:
    inner_l_mm: float
    inner_w_mm: float
    inner_h_mm: float
    wall_mm: float
    floor_mm: float
    corner_radius_mm: float
    pillar_d_mm: float
    pillar_hole_d_mm: float
    pillar_hole_depth_mm: float

    @property
    def rim_mm(self) -> float:
        return self.floor_mm + self.inner_h_mm

    @property
    def pillar_inset_mm(self) -> float:
        # The pillar's centre sits so that half the wall's thickness is shared with the
        # pillar: the screw gets a thick boss without the pillar taking much of the cavity.
        return self.pillar_d_mm / 2 - self.wall_mm / 2

    @property
    def pillar_reach_mm(self) -> float:
        """How far into the cavity, along x or y, a pillar reaches from the inner walls."""
        return self.pillar_inset_mm + self.pillar_d_mm / 2

    def pillar_centres(self) -> list[tuple[float, float]]:
        c = self.pillar_inset_mm
        xs = (c, self.inner_l_mm - c)
        ys = (c, self.inner_w_mm - c)
        return [(x, y) for y in ys for x in xs]

    def outline_box(self, z0: float, z1: float, grow_mm: float = 0.0) -> cq.Shape:
        w = self.wall_mm + grow_mm
        return rounded_box(
            -w,
            -w,
            z0,
            self.inner_l_mm + w,
            self.inner_w_mm + w,
            z1,
            self.corner_radius_mm + grow_mm,
        )

    def cavity_box(self, z0: float, z1: float, shrink_mm: float = 0.0) -> cq.Shape:
        r = max(self.corner_radius_mm - self.wall_mm - shrink_mm, 0.0)
        s = shrink_mm
        return rounded_box(s, s, z0, self.inner_l_mm - s, self.inner_w_mm - s, z1, r)

    def validate(self, names: dict[str, str]) -> None:
        """Check what every case needs; ``names`` maps these fields to the caller's names."""

        def n(field: str) -> str:
            return names.get(field, field)

        for field in ("wall_mm", "floor_mm", "inner_h_mm", "pillar_d_mm", "pillar_hole_d_mm"):
            if getattr(self, field) <= 0:
                raise ValueError(f"{n(field)} must be > 0")
        if self.pillar_d_mm < self.pillar_hole_d_mm + 2 * MIN_WEB_MM:
            raise ValueError(
                f"{n('pillar_d_mm')} must exceed the lid screw hole by {2 * MIN_WEB_MM} mm"
            )
        outer_web = self.pillar_inset_mm + self.wall_mm - self.pillar_hole_d_mm / 2
        if outer_web < MIN_WEB_MM:
            raise ValueError(
                f"{n('wall_mm')}: the lid screw hole would leave less than {MIN_WEB_MM} mm "
                "of wall outside it"
            )
        # The pillar must not break through the rounded outer corner.
        d = self.pillar_inset_mm + self.wall_mm
        r = self.corner_radius_mm
        if math.sqrt(2) * (r - d) + self.pillar_d_mm / 2 > r - MIN_WEB_MM / 2:
            raise ValueError(
                f"{n('corner_radius_mm')} is too large for the corner pillars "
                f"(keep it at most {self.max_corner_radius_mm():.1f} mm)"
            )
        if self.pillar_hole_depth_mm > self.inner_h_mm - MIN_WEB_MM:
            raise ValueError(f"{n('pillar_hole_depth_mm')} is deeper than the pillars")

    def max_corner_radius_mm(self) -> float:
        d = self.pillar_inset_mm + self.wall_mm
        # Solve sqrt(2) * (r - d) + pillar_r = r - web/2 for r.
        return (math.sqrt(2) * d - self.pillar_d_mm / 2 - MIN_WEB_MM / 2) / (math.sqrt(2) - 1)


def base_shell(shell: Shell, bottom_chamfer_mm: float) -> cq.Shape:
    """The open box with its lid-screw pillars; models add bosses, openings and fittings."""
    rim = shell.rim_mm
    outer = shell.outline_box(0, rim)
    if bottom_chamfer_mm > 0:
        # A chamfer, not a fillet, on the edge that lies on the print bed: a bottom fillet
        # would be an overhang, and the chamfer also hides the first layer's squash.
        wp = cq.Workplane("XY").add(outer).faces("<Z").chamfer(bottom_chamfer_mm)
        chamfered = wp.val()
        assert isinstance(chamfered, cq.Shape)
        outer = chamfered
    body = outer.cut(shell.cavity_box(shell.floor_mm, rim + 1))
    pillars = [
        cylinder((x, y, shell.floor_mm - 0.01), shell.pillar_d_mm, shell.inner_h_mm + 0.01)
        for x, y in shell.pillar_centres()
    ]
    body = body.fuse(*pillars)
    holes = [
        cylinder(
            (x, y, rim - shell.pillar_hole_depth_mm),
            shell.pillar_hole_d_mm,
            shell.pillar_hole_depth_mm + 1,
        )
        for x, y in shell.pillar_centres()
    ]
    return body.cut(*holes).clean()


def boss(
    x: float,
    y: float,
    z0: float,
    height_mm: float,
    d_mm: float,
    hole_d_mm: float,
    hole_bottom_z: float,
) -> tuple[cq.Shape, cq.Shape]:
    """A standoff from ``z0`` up and its blind pilot hole from ``hole_bottom_z`` up.

    The foot flares out where it meets the floor: a sharp inside corner is where a boss
    snaps off when a screw is overtightened. Returns (solid, hole cutter).
    """
    flare_mm = min(1.5, height_mm / 2)
    solid = cylinder((x, y, z0 - 0.01), d_mm, height_mm + 0.01).fuse(
        cone((x, y, z0 - 0.01), d_mm + 2 * flare_mm, d_mm, flare_mm + 0.01)
    )
    hole = cylinder((x, y, hole_bottom_z), hole_d_mm, z0 + height_mm - hole_bottom_z + 1)
    return solid, hole


def centred_positions(count: int, pitch_mm: float, centre_mm: float) -> list[float]:
    start = centre_mm - (count - 1) * pitch_mm / 2
    return [start + i * pitch_mm for i in range(count)]


def vertical_slots(
    normal: str,
    across: tuple[float, float],
    span: tuple[float, float],
    z_span: tuple[float, float],
    slot_w_mm: float,
    pitch_mm: float,
) -> list[cq.Shape]:
    """Vent slots through a wall normal to ``normal`` ('x' or 'y'), spread over ``span``.

    ``across`` is the range the cutter covers through the wall. The slots stand upright so
    each slot's top is a short bridge that a printer makes without support.
    """
    lo, hi = span
    if hi - lo < slot_w_mm or z_span[1] <= z_span[0]:
        return []
    count = int((hi - lo - slot_w_mm) // pitch_mm) + 1
    cutters = []
    for centre in centred_positions(count, pitch_mm, (lo + hi) / 2):
        a0, a1 = centre - slot_w_mm / 2, centre + slot_w_mm / 2
        if normal == "x":
            cutters.append(box(across[0], a0, z_span[0], across[1], a1, z_span[1]))
        else:
            cutters.append(box(a0, across[0], z_span[0], a1, across[1], z_span[1]))
    return cutters
