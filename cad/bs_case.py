"""Base-station case: the Raspberry Pi and the communication board, cooled by a lid fan.

What the 2019 thesis's case did (section 3.7.1, figures 3.25, 3.26 and 3.30), kept here:

- both boards protected, each on its own screw bosses, with every Pi socket reachable
  through an opening in the wall sized for the plug's moulded body;
- a 40 mm fan on the lid blows into a duct that splits the air in two: most of it straight
  down onto the heat-sinked SoC, part of it along a channel to a nozzle over the microSD card,
  which the thesis found overheating too; the air leaves through vent slots in the end walls;
- antenna holders: a shelf outside the wall next to the communication board carries SMA
  bulkheads (433 MHz radio, Bluetooth, and the feed of the GPS antenna on its own support),
  with a hole under each for the pigtail into the case.

Weather: the base station stands sheltered (indoors or in a cabinet on the roof): the fan
inlet faces up and the sockets are open, so this case is not rain-proof. The robot's case is.

Frame: see ``cad.enclosure``; x runs along the Pi (microSD end at x = 0), y across the Pi
and then the communication board.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import cadquery as cq

from cad import hardware
from cad.boards import BS_COMM_BOARD, RPI_4B, Board, Port, board_solid
from cad.checks import check_sizes
from cad.enclosure import (
    MIN_WEB_MM,
    base_shell,
    boss,
    case_shell,
    centred_positions,
    vertical_slots,
)
from cad.geometry import box, cone, cut, cylinder, fuse, single_solid, triangle_rib

# An opening whose top comes closer to the rim than this is opened up to the rim: a thinner
# bridge of wall above it would break off.
MIN_BRIDGE_MM = 3.0
# Narrowest post of wall left between two openings; closer openings become one.
MIN_POST_MM = 4.0
# Smallest duct passage worth printing: narrower passages clog with stringing.
MIN_PASSAGE_MM = 3.0


@dataclass(frozen=True)
class BsCaseParams:
    pi: Board = RPI_4B
    comm: Board = BS_COMM_BOARD
    # 2.4 mm = six perimeters of a 0.4 mm nozzle: stiff enough for plugging cables in.
    wall_mm: float = 2.4
    floor_mm: float = 2.4
    lid_mm: float = 2.4
    corner_radius_mm: float = 4.0
    bottom_chamfer_mm: float = 0.8
    lid_fillet_mm: float = 1.0
    # Gap between a board (or a socket's body) and anything of the case.
    clearance_mm: float = 1.0
    board_gap_mm: float = 4.0  # Pi to communication board: room for the GPIO jumpers
    sd_gap_mm: float = 11.0  # Pi's microSD edge to the wall: room for the SD air nozzle
    end_gap_mm: float = 9.5  # Pi's USB/Ethernet edge to the wall, past the lid pillars
    # Pi's power/HDMI edge to the wall: also keeps the USB opening off the corner pillar.
    side_gap_mm: float = 6.5
    # Floor to board bottom: the air path under the Pi and room for solder tails.
    standoff_mm: float = 6.0
    boss_d_mm: float = 5.5  # fits inside the Pi's 6 mm keep-out pads
    pi_pilot_d_mm: float = hardware.PILOT_M2_5_MM
    comm_pilot_d_mm: float = hardware.PILOT_M3_MM
    heatsink_mm: float = 8.0  # stick-on aluminium heat sink on the SoC; measure yours
    headroom_mm: float = 1.5  # tallest socket to the lid
    # Lid screws: M3 thread-forming screws, flat heads sunk in the lid.
    pillar_d_mm: float = 7.0
    lid_pilot_d_mm: float = hardware.PILOT_M3_MM
    lid_screw_depth_mm: float = 10.0
    lid_screw_d_mm: float = hardware.CLEAR_M3_MM
    lid_screw_head_d_mm: float = hardware.CSK_M3_HEAD_MM
    # The lid's locating lip drops inside the walls so it cannot slide off.
    lip_mm: float = 3.0
    lip_wall_mm: float = 1.6
    fit_mm: float = 0.3  # lip to wall: a sliding fit for PETG on a tuned printer
    port_margin_mm: float = 0.5  # around each plug opening
    # Cooling: the fan sits on the lid over the SoC.
    fan: hardware.Fan = hardware.FAN_4010
    grille_slot_mm: float = 3.0  # keeps fingers out of the blades
    grille_bar_mm: float = 2.0
    fan_boss_d_mm: float = 6.5
    duct_wall_mm: float = 1.2
    duct_gap_mm: float = 1.5  # duct above the heat sink
    cpu_outlet_mm: float = 22.0  # square opening over the SoC: sets the split
    sd_channel_w_mm: float = 12.0
    sd_channel_h_mm: float = 5.0
    vent_slot_w_mm: float = 2.0
    vent_pitch_mm: float = 5.0
    # Antenna holders.
    antennas: tuple[str, ...] = ("radio 433 MHz", "bluetooth", "gps feed")
    bulkhead: hardware.Bulkhead = hardware.SMA_BULKHEAD
    antenna_pitch_mm: float = 25.0
    shelf_mm: float = 3.0
    shelf_depth_mm: float = 16.0
    rib_mm: float = 2.4
    pigtail_hole_d_mm: float = 4.5  # passes a u.FL plug on a 1.13 mm coax

    def __post_init__(self) -> None:
        check_sizes(
            self,
            may_be_zero=(
                "corner_radius_mm",
                "bottom_chamfer_mm",
                "lid_fillet_mm",
                "heatsink_mm",
                "headroom_mm",
                "port_margin_mm",
            ),
        )
        if self.bottom_chamfer_mm >= min(self.wall_mm, self.floor_mm):
            raise ValueError("bottom_chamfer_mm must be smaller than wall_mm and floor_mm")
        if self.lid_fillet_mm >= self.lid_mm:
            raise ValueError("lid_fillet_mm must be smaller than lid_mm")
        for board, pilot in ((self.pi, "pi_pilot_d_mm"), (self.comm, "comm_pilot_d_mm")):
            if self.boss_d_mm > board.pad_d_mm:
                raise ValueError(
                    f"boss_d_mm ({self.boss_d_mm}) is wider than the {board.name}'s "
                    f"{board.pad_d_mm} mm pads: the boss would press on its parts"
                )
            if self.boss_d_mm < getattr(self, pilot) + 2 * MIN_WEB_MM:
                raise ValueError(f"boss_d_mm must be larger than {pilot} + {2 * MIN_WEB_MM} mm")
            if getattr(self, pilot) >= board.hole_d_mm:
                raise ValueError(f"{pilot} must be smaller than the {board.name}'s holes")
        if self.standoff_mm < max(self.pi.underside_mm, self.comm.underside_mm) + 1.0:
            raise ValueError("standoff_mm must leave 1 mm under the boards' solder tails")
        if self.lid_screw_d_mm <= self.lid_pilot_d_mm:
            raise ValueError("lid_screw_d_mm must be larger than lid_pilot_d_mm")
        if self.lid_screw_head_d_mm <= self.lid_screw_d_mm:
            raise ValueError("lid_screw_head_d_mm must be larger than lid_screw_d_mm")
        csk = (
            (self.lid_screw_head_d_mm - self.lid_screw_d_mm) / 2 / _tan_half(hardware.CSK_ANGLE_DEG)
        )
        if csk > self.lid_mm - 0.4:
            raise ValueError("lid_mm is too thin for the countersunk lid screws")
        if self.grille_slot_mm > 6.0:
            raise ValueError("grille_slot_mm above 6 mm lets a finger reach the fan blades")
        if self.cpu_outlet_mm > self.fan.size_mm - 2 * self.duct_wall_mm - 2 * MIN_PASSAGE_MM:
            raise ValueError("cpu_outlet_mm leaves no plenum floor to push air to the SD card")
        if min(self.sd_channel_w_mm, self.sd_channel_h_mm) < MIN_PASSAGE_MM:
            raise ValueError(f"the SD channel must be at least {MIN_PASSAGE_MM} mm each way")
        if self.shelf_mm > self.bulkhead.max_panel_mm:
            raise ValueError(
                f"shelf_mm ({self.shelf_mm}) is thicker than the bulkhead's "
                f"{self.bulkhead.max_panel_mm} mm panel limit"
            )
        if self.shelf_depth_mm < self.bulkhead.nut_clearance_d_mm:
            raise ValueError("shelf_depth_mm must leave room for a spanner on the bulkhead nut")
        if self.antenna_pitch_mm < self.bulkhead.nut_clearance_d_mm + self.rib_mm:
            raise ValueError("antenna_pitch_mm is too small for the nuts and the ribs between")
        if not self.antennas:
            raise ValueError("antennas must name at least one antenna holder")
        if self.vent_pitch_mm <= self.vent_slot_w_mm + 1.0:
            raise ValueError("vent_pitch_mm must leave at least 1 mm of wall between slots")
        self.layout  # noqa: B018 - computing the layout checks that everything fits

    @cached_property
    def layout(self) -> BsLayout:
        return BsLayout(self)


class BsLayout:
    """Where everything goes, in numbers; the solids are built from these."""

    def __init__(self, p: BsCaseParams) -> None:
        c = p.clearance_mm
        pi, comm = p.pi, p.comm
        if p.sd_gap_mm < pi.overhang_mm("x-") + c:
            raise ValueError("sd_gap_mm must clear the Pi's microSD card by clearance_mm")
        if p.end_gap_mm < pi.overhang_mm("x+") + c:
            raise ValueError("end_gap_mm must clear the Pi's USB/Ethernet by clearance_mm")
        if p.side_gap_mm < pi.overhang_mm("y-") + c:
            raise ValueError("side_gap_mm must clear the Pi's power and HDMI by clearance_mm")
        self.pi_x0 = p.sd_gap_mm
        self.pi_y0 = p.side_gap_mm
        self.comm_x0 = self.pi_x0
        self.comm_y0 = self.pi_y0 + pi.width_mm + p.board_gap_mm
        self.inner_l = self.pi_x0 + max(pi.length_mm, comm.length_mm) + p.end_gap_mm
        self.inner_w = self.comm_y0 + comm.width_mm + max(c, comm.overhang_mm("y+") + c)
        self.board_z = p.floor_mm + p.standoff_mm  # bottom face of both boards

        soc = next((comp for comp in pi.components if comp.name == "soc"), None)
        if soc is None:
            raise ValueError("pi has no 'soc' component for the fan to sit over")
        self.cpu_x = self.pi_x0 + soc.x_mm
        self.cpu_y = self.pi_y0 + soc.y_mm
        self.soc_top = self.board_z + pi.thickness_mm + soc.height_mm
        self.heatsink_top = self.soc_top + p.heatsink_mm
        self.heatsink_size = soc.length_mm - 1.0

        needs = {
            "pi": self.board_z + pi.top_mm + p.headroom_mm,
            "comm": self.board_z + comm.top_mm + p.headroom_mm,
            "duct": self.heatsink_top + p.duct_gap_mm + p.duct_wall_mm + p.sd_channel_h_mm,
        }
        self.rim = max(needs.values())
        self.duct_bottom = self.heatsink_top + p.duct_gap_mm

        self.shell = case_shell(
            p,
            inner_l_mm=self.inner_l,
            inner_w_mm=self.inner_w,
            inner_h_mm=self.rim - p.floor_mm,
            pillar_hole=(p.lid_pilot_d_mm, "lid_pilot_d_mm"),
        )
        self._check_pillars(p)
        self._check_openings(p)

        # The SD nozzle stands between the lid's lip and the Pi's edge, over the card.
        try:
            sd = pi.port("microsd")
        except KeyError:
            raise ValueError("pi has no 'microsd' port for the SD air nozzle to aim at") from None
        self.sd_y = self.pi_y0 + sd.along_mm
        self.nozzle_x0 = p.fit_mm + p.lip_wall_mm + 0.5
        self.nozzle_x1 = self.pi_x0 - 0.5
        if self.nozzle_x1 - self.nozzle_x0 - 2 * p.duct_wall_mm < MIN_PASSAGE_MM:
            raise ValueError("sd_gap_mm leaves no room for the SD air nozzle")
        self.nozzle_bottom = self.board_z + 0.5
        half_fan = p.fan.size_mm / 2
        if not (
            self.cpu_x - half_fan > self.nozzle_x1 + 1.0
            and self.cpu_y - half_fan > 0
            and self.cpu_y + half_fan < self.inner_w
        ):
            raise ValueError("the fan does not fit over the SoC inside the case")
        if abs(self.sd_y - self.cpu_y) + p.sd_channel_w_mm / 2 > half_fan - 2 * p.duct_wall_mm:
            raise ValueError("sd_channel_w_mm is too wide to leave the fan's duct")

        self.shelf_length = len(p.antennas) * p.antenna_pitch_mm
        if self.shelf_length > self.inner_l - 2 * self.shell.pillar_reach_mm:
            raise ValueError("the antenna shelf is longer than the case: fewer antennas or pitch")
        self.antenna_xs = centred_positions(len(p.antennas), p.antenna_pitch_mm, self.inner_l / 2)
        self.antenna_y = self.inner_w + p.wall_mm + p.shelf_depth_mm / 2
        self.pigtail_z = self.rim - p.shelf_mm - p.bulkhead.rear_mm / 2
        if self.pigtail_z - p.pigtail_hole_d_mm / 2 < self.board_z + comm.thickness_mm:
            raise ValueError("the pigtail holes would come below the communication board")

    def _check_pillars(self, p: BsCaseParams) -> None:
        reach = self.shell.pillar_d_mm / 2 + p.clearance_mm
        boards = (
            (self.pi_x0, self.pi_y0, p.pi),
            (self.comm_x0, self.comm_y0, p.comm),
        )
        for px, py in self.shell.pillar_centres():
            for x0, y0, board in boards:
                x1 = x0 + board.length_mm + board.overhang_mm("x+")
                x0 -= board.overhang_mm("x-")
                dx = max(x0 - px, px - x1, 0.0)
                dy = max(y0 - py, py - (y0 + board.width_mm), 0.0)
                if dx * dx + dy * dy < reach * reach:
                    name = "sd_gap_mm" if px < self.inner_l / 2 else "end_gap_mm"
                    raise ValueError(f"{name} is too small: the {board.name} hits a lid pillar")

    def _check_openings(self, p: BsCaseParams) -> None:
        """A plug opening must not cut into a corner pillar: the plug would hit it too."""
        keep = self.shell.pillar_reach_mm + MIN_WEB_MM
        for o in self._all_openings(p):
            length = self.inner_w if o.edge in ("x-", "x+") else self.inner_l
            if o.a0 < keep or o.a1 > length - keep:
                low = o.a0 < keep
                if o.edge in ("x-", "x+"):
                    name = "side_gap_mm" if low else "clearance_mm"
                else:
                    name = "sd_gap_mm" if low else "end_gap_mm"
                raise ValueError(f"{name} is too small: a plug opening runs into a lid pillar")

    def _opening(self, board: Board, x0: float, y0: float, port: Port, margin: float) -> _Opening:
        w = port.opening_w_mm + 2 * margin
        h = port.opening_h_mm + 2 * margin
        zc = self.board_z + board.thickness_mm + port.z_mm
        z0, z1 = zc - h / 2, zc + h / 2
        if z1 > self.rim - MIN_BRIDGE_MM:
            z1 = self.rim + 1.0
        along0 = (y0 if port.edge in ("x-", "x+") else x0) + port.along_mm
        if port.edge == "x-":
            face = x0 - port.overhang_mm
        elif port.edge == "x+":
            face = x0 + board.length_mm + port.overhang_mm
        elif port.edge == "y-":
            face = y0 - port.overhang_mm
        else:
            face = y0 + board.width_mm + port.overhang_mm
        return _Opening(port.edge, face, along0 - w / 2, along0 + w / 2, z0, z1)

    def openings(self, p: BsCaseParams) -> list[cq.Shape]:
        """Cutters for the plug openings, from each socket's face out through the wall.

        Openings closer than ``MIN_POST_MM`` merge into one: a thinner post of wall between
        them would snap off.
        """
        merged: list[_Opening] = []
        for o in sorted(self._all_openings(p), key=lambda o: (o.edge, o.a0)):
            last = merged[-1] if merged else None
            if last and last.edge == o.edge and o.a0 - last.a1 < MIN_POST_MM:
                merged[-1] = last.merge(o)
            else:
                merged.append(o)
        return [o.cutter() for o in merged]

    def _all_openings(self, p: BsCaseParams) -> list[_Opening]:
        found = [
            self._opening(p.pi, self.pi_x0, self.pi_y0, port, p.port_margin_mm)
            for port in p.pi.ports
        ]
        found += [
            self._opening(p.comm, self.comm_x0, self.comm_y0, port, p.port_margin_mm)
            for port in p.comm.ports
        ]
        return found


@dataclass(frozen=True)
class _Opening:
    edge: str
    face: float  # the socket's face: the cutter starts here and runs out through the wall
    a0: float  # extent along the wall
    a1: float
    z0: float
    z1: float

    def merge(self, other: _Opening) -> _Opening:
        inward = min if self.edge in ("x+", "y+") else max
        return _Opening(
            self.edge,
            inward(self.face, other.face),
            min(self.a0, other.a0),
            max(self.a1, other.a1),
            min(self.z0, other.z0),
            max(self.z1, other.z1),
        )

    def cutter(self) -> cq.Shape:
        far = 50.0  # well past the outer wall
        outward = far if self.edge in ("x+", "y+") else -far
        if self.edge in ("x-", "x+"):
            return box(self.face, self.a0, self.z0, self.face + outward, self.a1, self.z1)
        return box(self.a0, self.face, self.z0, self.a1, self.face + outward, self.z1)


@dataclass(frozen=True)
class BsCase:
    params: BsCaseParams
    base: cq.Solid
    lid: cq.Solid

    @property
    def layout(self) -> BsLayout:
        return self.params.layout

    def parts(self) -> dict[str, cq.Solid]:
        return {"base": self.base, "lid": self.lid}

    def boards(self) -> dict[str, cq.Shape]:
        """The boards in place (with the heat sink on the Pi), for checks and drawings."""
        p, lay = self.params, self.layout
        pi = board_solid(p.pi).translate(cq.Vector(lay.pi_x0, lay.pi_y0, lay.board_z))
        s = lay.heatsink_size
        sink = box(
            lay.cpu_x - s / 2,
            lay.cpu_y - s / 2,
            lay.soc_top,
            lay.cpu_x + s / 2,
            lay.cpu_y + s / 2,
            lay.heatsink_top,
        )
        comm = board_solid(p.comm).translate(cq.Vector(lay.comm_x0, lay.comm_y0, lay.board_z))
        return {"pi": fuse([pi, sink]) if p.heatsink_mm > 0 else pi, "comm": comm}

    def exploded(self, lift_mm: float = 30.0) -> cq.Shape:
        pieces: list[cq.Shape] = [self.base, self.lid.translate(cq.Vector(0, 0, lift_mm))]
        pieces += list(self.boards().values())
        return cq.Compound.makeCompound(pieces)


def build(params: BsCaseParams | None = None) -> BsCase:
    p = params or BsCaseParams()
    return BsCase(params=p, base=_base(p), lid=_lid(p))


def _base(p: BsCaseParams) -> cq.Solid:
    lay = p.layout
    shell = lay.shell
    body = base_shell(shell, p.bottom_chamfer_mm)

    solids: list[cq.Shape] = []
    holes: list[cq.Shape] = []
    for board, x0, y0, pilot in (
        (p.pi, lay.pi_x0, lay.pi_y0, p.pi_pilot_d_mm),
        (p.comm, lay.comm_x0, lay.comm_y0, p.comm_pilot_d_mm),
    ):
        for hx, hy in board.holes_mm:
            # The pilot goes into the floor too, leaving a 0.6 mm skin: longer thread grip.
            s, h = boss(x0 + hx, y0 + hy, p.floor_mm, p.standoff_mm, p.boss_d_mm, pilot, 0.6)
            solids.append(s)
            holes.append(h)

    solids += _shelf(p)
    body = body.fuse(*solids)

    cutters = lay.openings(p) + holes
    # Exhaust: the x- end wall above the SD opening, and the x+ end wall beside the
    # communication board, away from the Pi's sockets.
    wall = (-p.wall_mm - 1, 0.5)
    z_lo = lay.board_z + p.pi.thickness_mm + 2.0
    z_hi = lay.rim - p.lip_mm - 1.0
    reach = shell.pillar_reach_mm + 1.0
    cutters += vertical_slots(
        "x", wall, (reach, lay.inner_w - reach), (z_lo, z_hi), p.vent_slot_w_mm, p.vent_pitch_mm
    )
    far_wall = (lay.inner_l - 0.5, lay.inner_l + p.wall_mm + 1)
    cutters += vertical_slots(
        "x",
        far_wall,
        (lay.comm_y0 + 2.0, lay.inner_w - reach),
        (z_lo, z_hi),
        p.vent_slot_w_mm,
        p.vent_pitch_mm,
    )
    # Antenna bulkheads through the shelf, pigtail holes through the wall under it.
    for x in lay.antenna_xs:
        cutters.append(
            cylinder(
                (x, lay.antenna_y, lay.rim - p.shelf_mm - 1), p.bulkhead.hole_d_mm, p.shelf_mm + 2
            )
        )
        cutters.append(
            cylinder((x, lay.inner_w - 1, lay.pigtail_z), p.pigtail_hole_d_mm, p.wall_mm + 2, "Y")
        )
    return single_solid(cut(body, cutters), "bs_case base")


def _shelf(p: BsCaseParams) -> list[cq.Shape]:
    """The antenna shelf on the outer y+ wall, flush with the rim, on 45-degree ribs.

    45 degrees lets the ribs print without support; the shelf between them is a short bridge.
    """
    lay = p.layout
    y_wall = lay.inner_w + p.wall_mm
    x0 = lay.inner_l / 2 - lay.shelf_length / 2
    x1 = x0 + lay.shelf_length
    top = lay.rim
    pieces = [box(x0, y_wall - 0.5, top - p.shelf_mm, x1, y_wall + p.shelf_depth_mm, top)]
    rib_xs = [x0 + p.rib_mm / 2, x1 - p.rib_mm / 2]
    rib_xs += [x + p.antenna_pitch_mm / 2 for x in lay.antenna_xs[:-1]]
    depth = p.shelf_depth_mm
    for x in rib_xs:
        pieces.append(
            triangle_rib(
                (y_wall - 0.5, top - p.shelf_mm), depth + 0.5, -(depth + 0.5), "YZ", x, p.rib_mm
            )
        )
    return pieces


def _lid(p: BsCaseParams) -> cq.Solid:
    lay = p.layout
    shell = lay.shell
    top = lay.rim + p.lid_mm
    plate = shell.outline_box(lay.rim, top)
    if p.lid_fillet_mm > 0:
        wp = cq.Workplane("XY").add(plate).faces(">Z").edges().fillet(p.lid_fillet_mm)
        filleted = wp.val()
        assert isinstance(filleted, cq.Shape)
        plate = filleted

    lip_outer = shell.cavity_box(lay.rim - p.lip_mm, lay.rim + 0.01, p.fit_mm)
    lip_inner = shell.cavity_box(lay.rim - p.lip_mm - 1, lay.rim + 1, p.fit_mm + p.lip_wall_mm)
    pillar_room = [
        cylinder((x, y, lay.rim - p.lip_mm - 1), p.pillar_d_mm + 2 * p.fit_mm, p.lip_mm + 1)
        for x, y in shell.pillar_centres()
    ]
    lip = lip_outer.cut(lip_inner, *pillar_room, *lay.openings(p))

    lid = plate.fuse(lip, _duct(p), *_fan_bosses(p)).clean()

    cutters = [_grille(p)]
    half = p.fan.hole_pitch_mm / 2
    boss_depth = _fan_boss_depth(p)
    for dx in (-half, half):
        for dy in (-half, half):
            start = (lay.cpu_x + dx, lay.cpu_y + dy, lay.rim - boss_depth - 0.5)
            cutters.append(cylinder(start, hardware.PILOT_M3_MM, top - start[2] + 1))
    csk_depth = (p.lid_screw_head_d_mm - p.lid_screw_d_mm) / 2 / _tan_half(hardware.CSK_ANGLE_DEG)
    for x, y in shell.pillar_centres():
        cutters.append(cylinder((x, y, lay.rim - p.lip_mm - 1), p.lid_screw_d_mm, 20))
        cutters.append(
            cone(
                (x, y, top - csk_depth), p.lid_screw_d_mm, p.lid_screw_head_d_mm, csk_depth + 0.001
            )
        )
        cutters.append(cylinder((x, y, top), p.lid_screw_head_d_mm, 1))
    return single_solid(cut(lid, cutters), "bs_case lid")


def _tan_half(angle_deg: float) -> float:
    return math.tan(math.radians(angle_deg) / 2)


def _fan_bosses(p: BsCaseParams) -> list[cq.Shape]:
    """Bosses under the lid so the fan screws bite more than the lid's thickness."""
    lay = p.layout
    half = p.fan.hole_pitch_mm / 2
    depth = _fan_boss_depth(p)
    return [
        cylinder((lay.cpu_x + dx, lay.cpu_y + dy, lay.rim - depth), p.fan_boss_d_mm, depth + 0.01)
        for dx in (-half, half)
        for dy in (-half, half)
    ]


def _fan_boss_depth(p: BsCaseParams) -> float:
    return min(4.0, p.layout.rim - p.layout.duct_bottom - 0.5)


def _grille(p: BsCaseParams) -> cq.Shape:
    """Parallel slots over the fan's blades, clipped to the blades' circle."""
    lay = p.layout
    d = min(p.fan.bore_d_mm, p.fan.size_mm - 2 * p.duct_wall_mm)
    pitch = p.grille_slot_mm + p.grille_bar_mm
    count = int(d // pitch)
    z0, z1 = lay.rim - 0.2, lay.rim + p.lid_mm + 1
    slots = [
        box(
            x - p.grille_slot_mm / 2,
            lay.cpu_y - d / 2,
            z0,
            x + p.grille_slot_mm / 2,
            lay.cpu_y + d / 2,
            z1,
        )
        for x in centred_positions(count, pitch, lay.cpu_x)
    ]
    disc = cylinder((lay.cpu_x, lay.cpu_y, z0 - 1), d - 2 * p.grille_bar_mm, z1 - z0 + 2)
    return fuse(slots).intersect(disc)


def _duct(p: BsCaseParams) -> cq.Shape:
    """The air splitter under the fan: a plenum with an outlet over the SoC and a channel
    that carries part of the air to a nozzle over the microSD card.

    Built on its own so its inner cutters can reach the lid's underside without cutting the
    lid; printed with the lid upside down, the channel's floor is a short bridge.
    """
    lay = p.layout
    w = p.duct_wall_mm
    s = p.fan.size_mm / 2
    cx, cy, top = lay.cpu_x, lay.cpu_y, lay.rim + 0.01
    z_b = lay.duct_bottom
    cw, ch = p.sd_channel_w_mm / 2, p.sd_channel_h_mm
    outer = [
        box(cx - s, cy - s, z_b, cx + s, cy + s, top),
        box(lay.nozzle_x0, lay.sd_y - cw - w, lay.rim - ch - w, cx - s + w, lay.sd_y + cw + w, top),
        box(
            lay.nozzle_x0,
            lay.sd_y - cw - w,
            lay.nozzle_bottom,
            lay.nozzle_x1,
            lay.sd_y + cw + w,
            top,
        ),
    ]
    o = p.cpu_outlet_mm / 2
    inner = [
        box(cx - s + w, cy - s + w, z_b + w, cx + s - w, cy + s - w, top + 1),
        box(cx - o, cy - o, z_b - 1, cx + o, cy + o, z_b + w + 1),
        box(
            lay.nozzle_x0 + w, lay.sd_y - cw, lay.rim - ch, cx - s + w + 0.5, lay.sd_y + cw, top + 1
        ),
        box(
            lay.nozzle_x0 + w,
            lay.sd_y - cw,
            lay.nozzle_bottom - 1,
            lay.nozzle_x1 - w,
            lay.sd_y + cw,
            top + 1,
        ),
    ]
    return fuse(outer).cut(*inner).clean()
