"""Geometric probes: small solids pushed into a part to see whether material is there."""

from __future__ import annotations

import cadquery as cq

from cad.geometry import Axis, Point, box, cylinder, overlap_mm3

# How far a hole's axis may be from where the board's hole is and still count as lined up.
ALIGN_TOL_MM = 0.2
# Intersections below this are numerical noise, not material.
EMPTY_MM3 = 1e-3


def is_empty(probe: cq.Shape, *shapes: cq.Shape) -> bool:
    return all(overlap_mm3(probe, s) < EMPTY_MM3 for s in shapes)


def fill_ratio(probe: cq.Shape, shape: cq.Shape) -> float:
    """Share of the probe's volume that is material of ``shape``."""
    return overlap_mm3(probe, shape) / probe.Volume()


def rod(start: Point, diameter_mm: float, length_mm: float, axis: Axis = "Z") -> cq.Shape:
    return cylinder(start, diameter_mm, length_mm, axis)


def ring(
    start: Point, inner_d_mm: float, outer_d_mm: float, length_mm: float, axis: Axis = "Z"
) -> cq.Shape:
    return cylinder(start, outer_d_mm, length_mm, axis).cut(
        cylinder(start, inner_d_mm, length_mm, axis)
    )


def column(x0: float, y0: float, x1: float, y1: float, z0: float, z1: float) -> cq.Shape:
    return box(x0, y0, z0, x1, y1, z1)
