"""Robot case: the control board (Arduino Nano, RFM69 radio, RTK GPS, Bluetooth) on the rail.

The 2019 thesis's robot case (section 3.7.2, figure 3.28) protected the board and held it
to the robot's metal frame; this one does both and is made for the open roof:

- weather: a flat gasket (printed in TPU or cut from 2 mm EPDM sheet) is clamped between
  the rim and the lid by four M3 screws in heat-set inserts; the screws stand in corner
  pillars under the gasket, so water that follows a screw ends in a blind hole, not inside.
  The lid overhangs the walls with a skirt: a drip edge that keeps driven rain off the
  gasket line. Cables enter through glands and the antennas through SMA bulkheads, all on
  the end walls; nothing opens upwards. A membrane vent (M12) low on an end wall lets the
  case breathe, so it does not pump in moist air as it warms and cools, and the board
  stands on 8 mm bosses, well above any condensate on the floor;
- mounting: four tabs with slots along the rail's direction bolt the case to the frame
  (M6), so the frame's holes need not be where a drawing said;
- x- end: antenna bulkheads (433 MHz radio, Bluetooth, GPS) towards the antenna branch;
  x+ end: cable glands (battery supply, motor driver) and the vent.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cadquery as cq

from cad import hardware
from cad.boards import ROBOT_BOARD, Board, board_solid
from cad.checks import check_sizes
from cad.enclosure import MIN_WEB_MM, base_shell, boss, case_shell, centred_positions
from cad.geometry import (
    box,
    cut,
    cylinder,
    rounded_box,
    single_solid,
    slot,
    triangle_rib,
)


@dataclass(frozen=True)
class RobotCaseParams:
    board: Board = ROBOT_BOARD
    # 3 mm walls: outdoors, UV and knocks from the rail's surroundings; print in ASA or PETG.
    wall_mm: float = 3.0
    floor_mm: float = 3.0
    lid_mm: float = 3.0
    corner_radius_mm: float = 5.0
    bottom_chamfer_mm: float = 0.8
    lid_fillet_mm: float = 1.5  # rounds the lid's top edge so water runs off
    clearance_mm: float = 1.0
    antenna_gap_mm: float = 15.0  # board to the x- wall: the bulkheads' rear and coax bends
    gland_gap_mm: float = 15.0  # board to the x+ wall: gland locknuts and cable bends
    standoff_mm: float = 8.0
    boss_d_mm: float = 6.5
    pilot_d_mm: float = hardware.PILOT_M3_MM
    headroom_mm: float = 3.0  # wires over the modules
    pillar_d_mm: float = 8.0
    insert_hole_d_mm: float = hardware.INSERT_M3_HOLE_MM
    lid_screw_depth_mm: float = hardware.INSERT_M3_LENGTH_MM + 2.0
    lid_screw_d_mm: float = hardware.CLEAR_M3_MM
    gasket_mm: float = 2.0
    skirt_mm: float = 2.0  # the drip skirt's thickness
    skirt_gap_mm: float = 0.8  # skirt to wall: room for the gasket's bulge
    skirt_drop_mm: float = 6.0  # how far the skirt hangs below the lid's underside
    glands: tuple[str, ...] = ("battery", "motor driver")
    gland: hardware.Gland = hardware.M12_GLAND
    vent_d_mm: float = 12.5  # M12 x 1.5 pressure-compensation membrane vent
    fitting_pitch_mm: float = 19.0
    antennas: tuple[str, ...] = ("radio 433 MHz", "bluetooth", "gps")
    bulkhead: hardware.Bulkhead = hardware.SMA_BULKHEAD
    antenna_pitch_mm: float = 20.0
    # Frame tabs: M6 bolts; the slots run along x (the rail) to absorb the frame's tolerances.
    tab_mm: float = 5.0
    tab_reach_mm: float = 16.0
    tab_w_mm: float = 26.0
    tab_slot_w_mm: float = hardware.CLEAR_M6_MM
    tab_slot_len_mm: float = 14.0
    rib_mm: float = 3.0

    def __post_init__(self) -> None:
        check_sizes(
            self,
            may_be_zero=("corner_radius_mm", "bottom_chamfer_mm", "lid_fillet_mm", "headroom_mm"),
        )
        if self.bottom_chamfer_mm >= min(self.wall_mm, self.floor_mm):
            raise ValueError("bottom_chamfer_mm must be smaller than wall_mm and floor_mm")
        if self.lid_fillet_mm >= self.lid_mm:
            raise ValueError("lid_fillet_mm must be smaller than lid_mm")
        if self.boss_d_mm > self.board.pad_d_mm:
            raise ValueError(
                f"boss_d_mm ({self.boss_d_mm}) is wider than the board's {self.board.pad_d_mm} "
                "mm pads: the boss would press on its parts"
            )
        if self.boss_d_mm < self.pilot_d_mm + 2 * MIN_WEB_MM:
            raise ValueError(f"boss_d_mm must be larger than pilot_d_mm + {2 * MIN_WEB_MM} mm")
        if self.pilot_d_mm >= self.board.hole_d_mm:
            raise ValueError("pilot_d_mm must be smaller than the board's holes")
        if self.standoff_mm < self.board.underside_mm + 1.0:
            raise ValueError("standoff_mm must leave 1 mm under the board's solder tails")
        if self.lid_screw_d_mm >= self.pillar_d_mm - 2 * MIN_WEB_MM:
            raise ValueError("lid_screw_d_mm is too large for pillar_d_mm")
        if self.wall_mm > self.bulkhead.max_panel_mm:
            raise ValueError(
                f"wall_mm ({self.wall_mm}) is thicker than the bulkhead's "
                f"{self.bulkhead.max_panel_mm} mm panel limit"
            )
        if self.antenna_gap_mm < self.bulkhead.rear_mm + self.clearance_mm:
            raise ValueError("antenna_gap_mm leaves no room behind the antenna bulkheads")
        if self.gland_gap_mm < self.gland.inside_mm + self.clearance_mm:
            raise ValueError("gland_gap_mm leaves no room behind the cable glands")
        if self.fitting_pitch_mm < max(self.gland.locknut_d_mm, self.vent_d_mm + 4) + 1.0:
            raise ValueError("fitting_pitch_mm is too small for the gland locknuts")
        if self.antenna_pitch_mm < self.bulkhead.nut_clearance_d_mm + 1.0:
            raise ValueError("antenna_pitch_mm is too small for a spanner on the bulkhead nuts")
        if self.tab_slot_w_mm >= self.tab_w_mm - 2 * self.rib_mm - 4.0:
            raise ValueError("tab_slot_w_mm leaves too little tab around the slot")
        if self.tab_slot_len_mm < self.tab_slot_w_mm:
            raise ValueError("tab_slot_len_mm must be at least tab_slot_w_mm")
        if self.tab_slot_len_mm > self.tab_w_mm - 2 * self.rib_mm - 4.0:
            raise ValueError("tab_slot_len_mm is too long for tab_w_mm")
        if self.tab_reach_mm < self.tab_slot_w_mm + 2 * 3.0:
            raise ValueError("tab_reach_mm leaves too little tab around the slot")
        self.layout  # noqa: B018 - computing the layout checks that everything fits

    @cached_property
    def layout(self) -> RobotLayout:
        return RobotLayout(self)


class RobotLayout:
    def __init__(self, p: RobotCaseParams) -> None:
        b = p.board
        c = p.clearance_mm
        self.board_x0 = p.antenna_gap_mm
        self.board_y0 = c
        self.inner_l = p.antenna_gap_mm + b.length_mm + p.gland_gap_mm
        self.inner_w = b.width_mm + 2 * c
        self.board_z = p.floor_mm + p.standoff_mm
        self.rim = self.board_z + b.top_mm + p.headroom_mm
        self.shell = case_shell(
            p,
            inner_l_mm=self.inner_l,
            inner_w_mm=self.inner_w,
            inner_h_mm=self.rim - p.floor_mm,
            pillar_hole=(p.insert_hole_d_mm, "insert_hole_d_mm"),
        )
        reach = self.shell.pillar_reach_mm + c
        if p.antenna_gap_mm < reach:
            raise ValueError("antenna_gap_mm is too small: the board hits a lid pillar")
        if p.gland_gap_mm < reach:
            raise ValueError("gland_gap_mm is too small: the board hits a lid pillar")

        self.lid_bottom = self.rim + p.gasket_mm
        self.skirt_bottom = self.lid_bottom - p.skirt_drop_mm
        if self.skirt_bottom < p.tab_mm + 2.0:
            raise ValueError("skirt_drop_mm reaches down to the frame tabs")

        # Fittings on the x+ wall, low down: the vent between the glands.
        fittings = len(p.glands) + 1
        self.fitting_ys = centred_positions(fittings, p.fitting_pitch_mm, self.inner_w / 2)
        span_free = self.inner_w - 2 * self.shell.pillar_reach_mm
        if (fittings - 1) * p.fitting_pitch_mm + p.gland.locknut_d_mm > span_free:
            raise ValueError("the glands and the vent do not fit across the end wall")
        self.fitting_z = p.floor_mm + p.gland.locknut_d_mm / 2 + 1.0
        if self.fitting_z + p.gland.locknut_d_mm / 2 > self.skirt_bottom - 1.0:
            raise ValueError("the glands reach the lid's skirt: raise the walls (headroom_mm)")

        # Bulkheads on the x- wall, as high as the skirt allows (their nuts need a spanner).
        nut = p.bulkhead.nut_clearance_d_mm
        self.antenna_ys = centred_positions(len(p.antennas), p.antenna_pitch_mm, self.inner_w / 2)
        if (len(p.antennas) - 1) * p.antenna_pitch_mm + nut > span_free:
            raise ValueError("the antenna bulkheads do not fit across the end wall")
        self.antenna_z = self.skirt_bottom - 1.0 - nut / 2
        if self.antenna_z - nut / 2 < p.floor_mm + 1.0:
            raise ValueError("the antenna bulkheads reach the floor: raise the walls")

        # Tabs at the ends of the long walls, just clear of the rounded corners.
        end = p.wall_mm - p.corner_radius_mm - p.tab_w_mm / 2
        self.tab_xs = (-end, self.inner_l + end)

    def tab_slots(self, p: RobotCaseParams) -> list[tuple[float, float]]:
        """Centres of the four frame slots (x, y)."""
        y_off = p.wall_mm + p.tab_reach_mm / 2
        return [(x, y) for x in self.tab_xs for y in (-y_off, self.inner_w + y_off)]


@dataclass(frozen=True)
class RobotCase:
    params: RobotCaseParams
    base: cq.Solid
    gasket: cq.Solid
    lid: cq.Solid

    @property
    def layout(self) -> RobotLayout:
        return self.params.layout

    def parts(self) -> dict[str, cq.Solid]:
        return {"base": self.base, "gasket": self.gasket, "lid": self.lid}

    def boards(self) -> dict[str, cq.Shape]:
        lay = self.layout
        board = board_solid(self.params.board)
        return {"board": board.translate(cq.Vector(lay.board_x0, lay.board_y0, lay.board_z))}

    def exploded(self, lift_mm: float = 45.0) -> cq.Shape:
        pieces: list[cq.Shape] = [
            self.base,
            self.gasket.translate(cq.Vector(0, 0, lift_mm / 2)),
            self.lid.translate(cq.Vector(0, 0, lift_mm)),
            *self.boards().values(),
        ]
        return cq.Compound.makeCompound(pieces)


def build(params: RobotCaseParams | None = None) -> RobotCase:
    p = params or RobotCaseParams()
    return RobotCase(params=p, base=_base(p), gasket=_gasket(p), lid=_lid(p))


def _base(p: RobotCaseParams) -> cq.Solid:
    lay = p.layout
    body = base_shell(lay.shell, p.bottom_chamfer_mm)
    solids: list[cq.Shape] = []
    cutters: list[cq.Shape] = []
    for hx, hy in p.board.holes_mm:
        s, h = boss(
            lay.board_x0 + hx,
            lay.board_y0 + hy,
            p.floor_mm,
            p.standoff_mm,
            p.boss_d_mm,
            p.pilot_d_mm,
            0.8,
        )
        solids.append(s)
        cutters.append(h)
    solids += _tabs(p)
    body = body.fuse(*solids)

    through_x = p.wall_mm + 2
    x_plus = lay.inner_l - 1
    holes = [p.gland.hole_d_mm] * len(p.glands)
    holes.insert(len(holes) // 2, p.vent_d_mm)
    for y, d in zip(lay.fitting_ys, holes, strict=True):
        cutters.append(cylinder((x_plus, y, lay.fitting_z), d, through_x, "X"))
    for y in lay.antenna_ys:
        cutters.append(
            cylinder((-p.wall_mm - 1, y, lay.antenna_z), p.bulkhead.hole_d_mm, through_x, "X")
        )
    for x, y in lay.tab_slots(p):
        cutters.append(
            slot((x, y, p.tab_mm / 2), p.tab_slot_len_mm, p.tab_slot_w_mm, p.tab_mm + 2, "Z", "X")
        )
    return single_solid(cut(body, cutters), "robot_case base")


def _tabs(p: RobotCaseParams) -> list[cq.Shape]:
    """Frame tabs on the long walls with a gusset at each end of each tab."""
    lay = p.layout
    r = min(4.0, p.tab_w_mm / 2 - 0.1, p.tab_reach_mm / 2 - 0.1)
    pieces: list[cq.Shape] = []
    rib_h = min(p.tab_reach_mm * 0.8, lay.rim - p.tab_mm - 1.0)
    for x in lay.tab_xs:
        for side in (-1, 1):
            wall_y = -p.wall_mm if side < 0 else lay.inner_w + p.wall_mm
            # The tab starts inside the wall by its corner radius so only its outer
            # corners show rounded.
            y_in = wall_y - side * r
            y_out = wall_y + side * p.tab_reach_mm
            tab = rounded_box(
                x - p.tab_w_mm / 2,
                min(y_in, y_out),
                0,
                x + p.tab_w_mm / 2,
                max(y_in, y_out),
                p.tab_mm,
                r,
            )
            # A wall thinner than the radius would leave the tab's root in the cavity.
            inside = box(x - p.tab_w_mm, 0, -1, x + p.tab_w_mm, lay.inner_w, p.tab_mm + 1)
            pieces.append(tab.cut(inside))
            for rib_x in (x - p.tab_w_mm / 2 + p.rib_mm / 2, x + p.tab_w_mm / 2 - p.rib_mm / 2):
                leg = side * (p.tab_reach_mm - 2.0)
                pieces.append(
                    triangle_rib(
                        (wall_y - side * 0.5, p.tab_mm - 0.01),
                        leg + side * 0.5,
                        rib_h,
                        "YZ",
                        rib_x,
                        p.rib_mm,
                    )
                )
    return pieces


def _gasket(p: RobotCaseParams) -> cq.Solid:
    """The flat gasket: the rim's outline plus the pillar tops, with the screw holes."""
    lay = p.layout
    shell = lay.shell
    z0, z1 = lay.rim, lay.rim + p.gasket_mm
    ring = shell.outline_box(z0, z1).cut(shell.cavity_box(z0 - 1, z1 + 1))
    caps = [cylinder((x, y, z0), p.pillar_d_mm, p.gasket_mm) for x, y in shell.pillar_centres()]
    holes = [
        cylinder((x, y, z0 - 1), p.lid_screw_d_mm, p.gasket_mm + 2)
        for x, y in shell.pillar_centres()
    ]
    return single_solid(cut(ring.fuse(*caps), holes), "robot_case gasket")


def _lid(p: RobotCaseParams) -> cq.Solid:
    lay = p.layout
    shell = lay.shell
    z0 = lay.lid_bottom
    top = z0 + p.lid_mm
    grow = p.skirt_gap_mm + p.skirt_mm
    plate = shell.outline_box(z0, top, grow)
    if p.lid_fillet_mm > 0:
        wp = cq.Workplane("XY").add(plate).faces(">Z").edges().fillet(p.lid_fillet_mm)
        filleted = wp.val()
        assert isinstance(filleted, cq.Shape)
        plate = filleted
    skirt = shell.outline_box(lay.skirt_bottom, z0 + 0.01, grow).cut(
        shell.outline_box(lay.skirt_bottom - 1, z0 + 1, p.skirt_gap_mm)
    )
    lid = plate.fuse(skirt).clean()
    holes = [
        cylinder((x, y, z0 - 1), p.lid_screw_d_mm, p.lid_mm + 2) for x, y in shell.pillar_centres()
    ]
    return single_solid(cut(lid, holes), "robot_case lid")
