"""Small solid-building helpers shared by the models.

Every model builds in one frame: millimetres, z up, the part's bottom face on z = 0 unless a
model says otherwise. The helpers return OpenCascade shapes (``cq.Shape``) rather than
workplanes so that a model can collect many cutters and cut them in one boolean, which is
both faster and more robust than a chain of single cuts.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Literal

import cadquery as cq
from OCP.Bnd import Bnd_Box
from OCP.BRepBndLib import BRepBndLib

Axis = Literal["X", "Y", "Z"]
Point = tuple[float, float, float]

_AXES: dict[Axis, cq.Vector] = {
    "X": cq.Vector(1, 0, 0),
    "Y": cq.Vector(0, 1, 0),
    "Z": cq.Vector(0, 0, 1),
}


def box(x0: float, y0: float, z0: float, x1: float, y1: float, z1: float) -> cq.Shape:
    """An axis-aligned box between two opposite corners (in any order)."""
    lo = (min(x0, x1), min(y0, y1), min(z0, z1))
    size = (abs(x1 - x0), abs(y1 - y0), abs(z1 - z0))
    if min(size) <= 0:
        raise ValueError(f"degenerate box {size}")
    return cq.Solid.makeBox(*size, pnt=cq.Vector(*lo))


def centred_box(centre: Point, size_x: float, size_y: float, size_z: float) -> cq.Shape:
    cx, cy, cz = centre
    return box(
        cx - size_x / 2,
        cy - size_y / 2,
        cz - size_z / 2,
        cx + size_x / 2,
        cy + size_y / 2,
        cz + size_z / 2,
    )


def rounded_box(
    x0: float, y0: float, z0: float, x1: float, y1: float, z1: float, radius_mm: float
) -> cq.Shape:
    """A box whose four vertical edges are rounded; radius 0 gives sharp corners."""
    length, width, height = abs(x1 - x0), abs(y1 - y0), abs(z1 - z0)
    if radius_mm <= 0:
        return box(x0, y0, z0, x1, y1, z1)
    # A fillet that eats a whole side would leave a degenerate face.
    radius_mm = min(radius_mm, length / 2 - 0.01, width / 2 - 0.01)
    sketch = cq.Sketch().rect(length, width).vertices().fillet(radius_mm)
    solid = cq.Workplane("XY").placeSketch(sketch).extrude(height).val()
    assert isinstance(solid, cq.Shape)
    return solid.translate(cq.Vector((x0 + x1) / 2, (y0 + y1) / 2, min(z0, z1)))


def cylinder(start: Point, diameter_mm: float, length_mm: float, axis: Axis = "Z") -> cq.Shape:
    """A cylinder starting at ``start`` and running ``length_mm`` along +axis."""
    return cq.Solid.makeCylinder(diameter_mm / 2, length_mm, cq.Vector(*start), _AXES[axis])


def through_cylinder(
    centre: Point, diameter_mm: float, length_mm: float, axis: Axis = "Z"
) -> cq.Shape:
    """A cylinder centred on ``centre`` along ``axis``: a drill that goes both ways."""
    direction = _AXES[axis]
    start = cq.Vector(*centre) - direction * (length_mm / 2)
    return cq.Solid.makeCylinder(diameter_mm / 2, length_mm, start, direction)


def cone(start: Point, d0_mm: float, d1_mm: float, length_mm: float) -> cq.Shape:
    """A vertical frustum from diameter ``d0_mm`` at ``start`` to ``d1_mm`` above it."""
    return cq.Solid.makeCone(d0_mm / 2, d1_mm / 2, length_mm, cq.Vector(*start))


def slot(
    centre: Point, length_mm: float, width_mm: float, depth_mm: float, axis: Axis, along: Axis
) -> cq.Shape:
    """A round-ended slot cutter: ``axis`` is the drilling direction, ``along`` its length."""
    if axis == along:
        raise ValueError("a slot's length cannot lie along its drilling axis")
    half = max(length_mm - width_mm, 0.0) / 2
    direction = _AXES[along]
    ends = [cq.Vector(*centre) + direction * s for s in (-half, half)]
    parts = [through_cylinder((e.x, e.y, e.z), width_mm, depth_mm, axis) for e in ends]
    if half > 0:
        size = {a: width_mm for a in ("X", "Y", "Z")}
        size[along] = 2 * half
        size[axis] = depth_mm
        parts.append(centred_box(centre, size["X"], size["Y"], size["Z"]))
    return fuse(parts)


def triangle_rib(
    corner: tuple[float, float],
    leg_a_mm: float,
    leg_b_mm: float,
    plane: Literal["XZ", "YZ"],
    offset_mm: float,
    thickness_mm: float,
) -> cq.Shape:
    """A right-triangle gusset in a vertical plane, centred on ``offset_mm`` across it.

    ``corner`` is the right angle in the plane's own (u, z) coordinates; the legs run along +u
    by ``leg_a_mm`` (signed) and along +z by ``leg_b_mm`` (signed).
    """
    u0, z0 = corner
    pts = [(u0, z0), (u0 + leg_a_mm, z0), (u0, z0 + leg_b_mm)]
    if plane == "XZ":
        wp = cq.Workplane("XZ", origin=(0, offset_mm + thickness_mm / 2, 0))
    else:
        wp = cq.Workplane("YZ", origin=(offset_mm - thickness_mm / 2, 0, 0))
    solid = wp.polyline(pts).close().extrude(thickness_mm).val()
    assert isinstance(solid, cq.Shape)
    return solid


def fuse(shapes: Iterable[cq.Shape]) -> cq.Shape:
    items = list(shapes)
    if not items:
        raise ValueError("nothing to fuse")
    first, rest = items[0], items[1:]
    return first.fuse(*rest).clean() if rest else first


def cut(shape: cq.Shape, cutters: Sequence[cq.Shape]) -> cq.Shape:
    return shape.cut(*cutters).clean() if cutters else shape


def single_solid(shape: cq.Shape, name: str) -> cq.Solid:
    """The one solid of a boolean result; two solids mean a part fell apart."""
    solids = shape.Solids()
    if len(solids) != 1:
        raise ValueError(f"{name}: expected one solid, got {len(solids)}")
    return solids[0]


def overlap_mm3(a: cq.Shape, b: cq.Shape) -> float:
    """Volume shared by two shapes (0 when they only touch)."""
    common = a.intersect(b)
    return sum(s.Volume() for s in common.Solids())


def exact_bounds(shape: cq.Shape) -> cq.BoundBox:
    """The bounding box from the exact geometry.

    ``Shape.BoundingBox`` uses a mesh when the shape carries one (an STL export leaves one
    behind), which can be off by the mesh's chord error.
    """
    bbox = Bnd_Box()
    BRepBndLib.AddOptimal_s(shape.wrapped, bbox, False, False)
    return cq.BoundBox(bbox)


def polar(radius_mm: float, angle_deg: float) -> tuple[float, float]:
    """A point at ``radius_mm`` and ``angle_deg`` from +u towards +v."""
    a = math.radians(angle_deg)
    return radius_mm * math.cos(a), radius_mm * math.sin(a)
