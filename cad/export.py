"""Writing parts to disk: STEP for machining and CAD, STL for printing, SVG for reading."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import cadquery as cq
from cadquery.occ_impl.exporters.svg import getSVG
from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt

from cad.geometry import exact_bounds

# Chord error 0.02 mm: below a printer's resolution, so curved faces print round; the
# angular limit keeps small holes from turning into polygons.
STL_TOLERANCE_MM = 0.02
STL_ANGULAR_TOLERANCE_RAD = 0.1

# A view from the front, right and above, the way a part is drawn in an assembly sheet.
SVG_VIEW = (1.0, -1.4, 1.1)


@dataclass(frozen=True)
class PartSummary:
    name: str
    size_mm: tuple[float, float, float]
    volume_mm3: float


def write_step(shape: cq.Shape, path: Path) -> Path:
    cq.exporters.export(shape, str(path), exportType="STEP")
    return path


def write_stl(shape: cq.Shape, path: Path) -> Path:
    # Meshing stores the mesh on the shape it is given: mesh a copy, keep the part clean.
    cq.exporters.export(
        shape.copy(),
        str(path),
        exportType="STL",
        tolerance=STL_TOLERANCE_MM,
        angularTolerance=STL_ANGULAR_TOLERANCE_RAD,
    )
    return path


def upright(shape: cq.Shape, view: tuple[float, float, float]) -> cq.Shape:
    """The shape turned about the line of sight so that +z is drawn pointing up.

    The projection picks its own in-plane axes from the view direction alone, which would
    draw the parts lying on their side.
    """
    d = cq.Vector(*view).normalized()
    frame = gp_Ax2(gp_Pnt(), gp_Dir(d.x, d.y, d.z))
    x_dir, y_dir = cq.Vector(frame.XDirection()), cq.Vector(frame.YDirection())
    z = cq.Vector(0, 0, 1)
    up = (z - d * z.dot(d)).normalized()
    drawn_at_deg = math.degrees(math.atan2(up.dot(y_dir), up.dot(x_dir)))
    return shape.rotate(cq.Vector(0, 0, 0), d, 90.0 - drawn_at_deg)


def write_svg(shape: cq.Shape, path: Path, height_px: int = 420) -> Path:
    """A hidden-line projection, its width fitted to the drawing.

    Hidden edges are left out so the drawing stays readable, and coordinates are rounded to
    0.01 mm: far below a pixel, and it halves the file that the repository keeps.
    """
    text = getSVG(
        upright(shape, SVG_VIEW),
        {
            "width": None,
            "height": height_px,
            "marginLeft": 10,
            "marginTop": 10,
            "projectionDir": SVG_VIEW,
            "showAxes": False,
            "showHidden": False,
            "strokeWidth": 0.3,
        },
    )
    path.write_text(_NUMBER.sub(_round, text), encoding="utf-8")
    return path


_NUMBER = re.compile(r"-?\d+\.\d{3,}")


def _round(match: re.Match[str]) -> str:
    text = f"{float(match.group()):.2f}".rstrip("0").rstrip(".")
    return "0" if text == "-0" else text


def summarise(name: str, shape: cq.Shape) -> PartSummary:
    bb = exact_bounds(shape)
    return PartSummary(name=name, size_mm=(bb.xlen, bb.ylen, bb.zlen), volume_mm3=shape.Volume())
