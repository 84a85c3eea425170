"""The circuit boards the enclosures hold: outline, mounting holes, connectors, tall parts.

A board is described in its own frame: origin at the corner of the outline nearest the
``x-``/``y-`` edges, the board's bottom face on z = 0. Each connector is on an edge
(``x-``, ``x+``, ``y-``, ``y+``) and sticks out past it by ``overhang_mm``; the wall opening in
front of it is sized for the mating plug's moulded body, which is larger than the socket.

Where a number comes from a published drawing, the docstring says so. The two carrier boards
are the project's own hand-built boards (thesis figure 3.3): their numbers are placeholders to
be replaced by measurements before anything is printed; ``cad/README.md`` lists what to measure.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cadquery as cq

from cad.geometry import box, cylinder, fuse, rounded_box

Edge = Literal["x-", "x+", "y-", "y+"]


@dataclass(frozen=True)
class Port:
    """A connector reached through the enclosure wall."""

    name: str
    edge: Edge
    along_mm: float  # centre along the edge, in board coordinates
    width_mm: float  # socket body, along the edge
    height_mm: float  # socket body, vertical
    z_mm: float  # centre height above the board's top face (negative: under the board)
    depth_mm: float  # socket body, perpendicular to the edge
    overhang_mm: float  # how far the body sticks out past the edge
    opening_w_mm: float  # what the plug's moulded body needs, along the edge
    opening_h_mm: float  # what the plug's moulded body needs, vertically

    def __post_init__(self) -> None:
        for name in ("width_mm", "height_mm", "depth_mm", "opening_w_mm", "opening_h_mm"):
            if getattr(self, name) <= 0:
                raise ValueError(f"port {self.name}: {name} must be > 0")
        if self.overhang_mm < 0 or self.overhang_mm >= self.depth_mm:
            raise ValueError(f"port {self.name}: overhang_mm must be in [0, depth_mm)")
        if self.opening_w_mm < self.width_mm or self.opening_h_mm < self.height_mm:
            raise ValueError(f"port {self.name}: the opening must be at least the socket's size")


@dataclass(frozen=True)
class Component:
    """A tall part on the board, as the box it occupies (centre x, y in board coordinates)."""

    name: str
    x_mm: float
    y_mm: float
    length_mm: float  # along x
    width_mm: float  # along y
    height_mm: float  # above the board's top face


@dataclass(frozen=True)
class Board:
    name: str
    length_mm: float  # along x
    width_mm: float  # along y
    thickness_mm: float
    corner_radius_mm: float
    hole_d_mm: float
    holes_mm: tuple[tuple[float, float], ...]
    # Copper-free ring around each hole where a standoff may press on the board.
    pad_d_mm: float
    # Solder tails and bottom-side parts: nothing but standoffs may come closer to the board.
    underside_mm: float
    # Low parts all over the top side (everything but the pads, where screw heads sit).
    topside_mm: float = 0.0
    ports: tuple[Port, ...] = ()
    components: tuple[Component, ...] = ()

    def __post_init__(self) -> None:
        for name in ("length_mm", "width_mm", "thickness_mm", "hole_d_mm", "pad_d_mm"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{self.name}: {name} must be > 0")
        if self.underside_mm < 0 or self.corner_radius_mm < 0:
            raise ValueError(f"{self.name}: underside_mm and corner_radius_mm must be >= 0")
        if self.pad_d_mm <= self.hole_d_mm:
            raise ValueError(f"{self.name}: pad_d_mm must be larger than hole_d_mm")
        if not self.holes_mm:
            raise ValueError(f"{self.name}: a board needs mounting holes")
        r = self.pad_d_mm / 2
        for x, y in self.holes_mm:
            if not (r <= x <= self.length_mm - r and r <= y <= self.width_mm - r):
                raise ValueError(f"{self.name}: hole ({x}, {y}) is off the board")
        for c in self.components:
            inside = (
                c.length_mm / 2 <= c.x_mm <= self.length_mm - c.length_mm / 2
                and c.width_mm / 2 <= c.y_mm <= self.width_mm - c.width_mm / 2
            )
            if not inside or min(c.length_mm, c.width_mm, c.height_mm) <= 0:
                raise ValueError(f"{self.name}: component {c.name} does not sit on the board")
            for x, y in self.holes_mm:
                # A part over a pad would sit where the screw head and the screwdriver go.
                dx = max(abs(x - c.x_mm) - c.length_mm / 2, 0.0)
                dy = max(abs(y - c.y_mm) - c.width_mm / 2, 0.0)
                if dx * dx + dy * dy < r * r - 1e-9:
                    raise ValueError(f"{self.name}: component {c.name} covers hole ({x}, {y})")

    @property
    def top_mm(self) -> float:
        """Height of the tallest thing above the board's bottom face."""
        tops = [p.z_mm + p.height_mm / 2 for p in self.ports]
        tops += [c.height_mm for c in self.components]
        return self.thickness_mm + max([self.topside_mm, *tops])

    def overhang_mm(self, edge: Edge) -> float:
        return max([0.0, *(p.overhang_mm for p in self.ports if p.edge == edge)])

    def port(self, name: str) -> Port:
        for p in self.ports:
            if p.name == name:
                return p
        raise KeyError(name)


def port_body(board: Board, port: Port) -> cq.Shape:
    """The socket's body as a box in board coordinates."""
    z = board.thickness_mm + port.z_mm
    z0, z1 = z - port.height_mm / 2, z + port.height_mm / 2
    a0, a1 = port.along_mm - port.width_mm / 2, port.along_mm + port.width_mm / 2
    inner = port.depth_mm - port.overhang_mm
    if port.edge == "x-":
        return box(-port.overhang_mm, a0, z0, inner, a1, z1)
    if port.edge == "x+":
        return box(board.length_mm - inner, a0, z0, board.length_mm + port.overhang_mm, a1, z1)
    if port.edge == "y-":
        return box(a0, -port.overhang_mm, z0, a1, inner, z1)
    return box(a0, board.width_mm - inner, z0, a1, board.width_mm + port.overhang_mm, z1)


def board_solid(board: Board) -> cq.Shape:
    """Everything the board occupies: PCB, sockets, tall parts and the space under it.

    The space under the board leaves the pads free, so a standoff no wider than the pad does
    not count as touching the board.
    """
    t = board.thickness_mm
    holes = [cylinder((x, y, -1), board.hole_d_mm, t + 2) for x, y in board.holes_mm]
    pcb = rounded_box(0, 0, 0, board.length_mm, board.width_mm, t, board.corner_radius_mm)
    pieces = [pcb.cut(*holes)]
    for z0, z1 in ((-board.underside_mm, 0.0), (t, t + board.topside_mm)):
        if z1 - z0 <= 0:
            continue
        layer = rounded_box(0, 0, z0, board.length_mm, board.width_mm, z1, board.corner_radius_mm)
        pads = [cylinder((x, y, z0 - 1), board.pad_d_mm, z1 - z0 + 2) for x, y in board.holes_mm]
        pieces.append(layer.cut(*pads))
    pieces += [port_body(board, p) for p in board.ports]
    for c in board.components:
        pieces.append(
            box(
                c.x_mm - c.length_mm / 2,
                c.y_mm - c.width_mm / 2,
                t,
                c.x_mm + c.length_mm / 2,
                c.y_mm + c.width_mm / 2,
                t + c.height_mm,
            )
        )
    return fuse(pieces)


def _corner_holes(length: float, width: float, inset: float) -> tuple[tuple[float, float], ...]:
    return (
        (inset, inset),
        (length - inset, inset),
        (inset, width - inset),
        (length - inset, width - inset),
    )


# Raspberry Pi 4 Model B, from the Raspberry Pi Foundation's mechanical drawing: 85 x 56 mm,
# 3 mm corners, four 2.7 mm holes on a 58 x 49 mm pattern 3.5 mm from the edges with 6 mm
# keep-out pads, USB-C / micro-HDMI / audio centres at 11.2 / 26.0 / 39.5 / 54.0 mm on the
# y- edge and USB 2.0 / USB 3.0 / Ethernet centres at 9.0 / 27.0 / 45.75 mm on the x+ edge.
# Socket body sizes, overhangs and the SoC position are measured from boards and photos, not
# from the drawing: check them (calipers) on the Pi you mount. The opening sizes are for
# common moulded cables.
RPI_4B = Board(
    name="Raspberry Pi 4 Model B",
    length_mm=85.0,
    width_mm=56.0,
    thickness_mm=1.4,
    corner_radius_mm=3.0,
    hole_d_mm=2.7,
    holes_mm=((3.5, 3.5), (61.5, 3.5), (3.5, 52.5), (61.5, 52.5)),
    pad_d_mm=6.0,
    underside_mm=2.0,
    topside_mm=5.5,  # SMD parts, CSI/DSI sockets
    ports=(
        Port("usb-c power", "y-", 11.2, 9.0, 3.3, 1.65, 7.5, 1.2, 12.5, 7.0),
        Port("micro-hdmi 0", "y-", 26.0, 7.0, 3.0, 1.5, 7.5, 1.0, 11.5, 7.5),
        Port("micro-hdmi 1", "y-", 39.5, 7.0, 3.0, 1.5, 7.5, 1.0, 11.5, 7.5),
        Port("audio", "y-", 54.0, 7.0, 6.0, 3.0, 12.0, 0.5, 8.0, 8.0),
        Port("usb 2.0", "x+", 9.0, 13.5, 16.0, 8.0, 17.5, 2.5, 15.0, 17.0),
        Port("usb 3.0", "x+", 27.0, 13.5, 16.0, 8.0, 17.5, 2.5, 15.0, 17.0),
        Port("ethernet", "x+", 45.75, 16.0, 13.5, 6.75, 21.0, 2.5, 16.5, 14.0),
        # The microSD card sits under the board and sticks out of the x- edge.
        Port("microsd", "x-", 28.0, 11.5, 1.5, -2.15, 15.0, 2.5, 14.0, 4.0),
    ),
    components=(
        Component("soc", 29.0, 32.5, 15.0, 15.0, 2.4),
        Component("gpio header", 32.5, 52.5, 51.0, 5.0, 8.5),
    ),
)

# Arduino Nano, from Arduino's product page: 45 x 18 mm. Here as a part on the robot's carrier
# board, standing on female headers (8.5 mm) with its own parts on top.
ARDUINO_NANO_MM = (45.0, 18.0)
ARDUINO_NANO_ON_HEADERS_MM = 15.0

# Adafruit RFM69HCW 433 MHz breakout (product 3071): about 29 x 25 mm on pin headers. Nominal
# from the vendor's listing: measure.
RFM69HCW_BREAKOUT_MM = (29.0, 25.0)
RFM69HCW_ON_HEADERS_MM = 11.0

# NS-HP-GL RTK receiver and RN41XV Bluetooth module (XBee footprint 24.4 x 27.6 mm) on the
# robot's carrier. The receiver's footprint is a placeholder: measure it.
NS_HP_GL_MM = (40.0, 30.0)
RN41XV_MM = (24.4, 27.6)
MODULE_ON_HEADERS_MM = 12.0

# The robot's control board (thesis figure 3.3a): a hand-built carrier with the Nano, the
# radio, the GPS and the Bluetooth module. Outline, holes and heights are placeholders for a
# 100 x 70 mm prototyping board with M3 holes 4 mm from the corners: measure the real one.
ROBOT_BOARD = Board(
    name="robot control board",
    length_mm=100.0,
    width_mm=70.0,
    thickness_mm=1.6,
    corner_radius_mm=1.0,
    hole_d_mm=3.2,
    holes_mm=_corner_holes(100.0, 70.0, 4.0),
    pad_d_mm=7.0,
    underside_mm=2.5,
    components=(
        Component("arduino nano", 31.5, 14.0, *ARDUINO_NANO_MM, ARDUINO_NANO_ON_HEADERS_MM),
        Component("rfm69hcw", 75.0, 17.5, *RFM69HCW_BREAKOUT_MM, RFM69HCW_ON_HEADERS_MM),
        Component("ns-hp-gl gps", 30.0, 50.0, *NS_HP_GL_MM, MODULE_ON_HEADERS_MM),
        Component("rn41xv bluetooth", 75.0, 50.0, *RN41XV_MM, MODULE_ON_HEADERS_MM),
    ),
)

# The base station's communication board (thesis figure 3.3b): radio, GPS, Bluetooth and a
# USB-UART converter, wired to the Pi's GPIO header. Placeholder for a 70 x 50 mm
# prototyping board with M3 holes 3.5 mm from the corners: measure the real one.
BS_COMM_BOARD = Board(
    name="base-station communication board",
    length_mm=70.0,
    width_mm=50.0,
    thickness_mm=1.6,
    corner_radius_mm=1.0,
    hole_d_mm=3.2,
    holes_mm=_corner_holes(70.0, 50.0, 3.5),
    pad_d_mm=6.0,
    underside_mm=2.5,
    components=(
        Component("rfm69hcw", 21.0, 17.0, *RFM69HCW_BREAKOUT_MM, RFM69HCW_ON_HEADERS_MM),
        Component("modules", 46.0, 32.0, 34.0, 26.0, MODULE_ON_HEADERS_MM),
    ),
)
