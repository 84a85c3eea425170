"""The rail: a closed polyline of GPS points, and where a GPS position lies along it.

The geometry is configuration (a JSON or TOML file), checked whole at start so that a
mistyped file stops the agent with a message naming the field instead of putting samples
at wrong places. Positions are worked out in a local equirectangular frame in metres around
the building centre: over a rooftop (tens of metres) its error is far below the GPS's.

Along-track positions (``track_m``) grow clockwise seen from above (north up), the agent's
convention for ``direction="cw"``, whatever order the file lists the points in; they count
from the ``origin`` point (the first point by default) and lie in ``[0, length_m)``.

The thesis grid id (§3.4, figure 3.23) is independent of the polyline: the bearing of the
position from the building centre picks a side — A between north and east, B east to south,
C south to west, D west to north — and the side is cut into ``grid_points / 4`` equal angles,
numbered from 1 clockwise, e.g. ``A2``.

The simulator drives its robot along the same :class:`Rail` (``SimConfig.rail``), so the
simulated GPS and the agent's projection always agree about where the rail is.

One thing: the rail's geometry, with the checks of its configuration file, which name the field
at fault in the same terms the geometry uses.
"""

from __future__ import annotations

import bisect
import json
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

# Mean Earth radius (IUGG): the local frame only needs to be consistent, not survey-grade.
EARTH_RADIUS_M: Final = 6_371_008.8
# The thesis's centre of IT1, Aveiro (getPosId in §3.4).
THESIS_CENTRE: Final = (40.634172, -8.660015)
DEFAULT_GRID_POINTS: Final = 16
# The equirectangular frame stays within millimetres of the truth over a few kilometres.
MAX_DISTANCE_FROM_CENTRE_M: Final = 5_000.0
# Geometry checks are quadratic in the points; a rooftop rail needs a few dozen.
MAX_POINTS: Final = 500
# Points closer than this are "the same point": an edge this short has no direction.
MIN_EDGE_M: Final = 0.01
# The origin must lie on the rail; this allows for a hand-surveyed origin point.
MAX_ORIGIN_OFFSET_M: Final = 5.0
MAX_GRID_POINTS: Final = 400
# The testbed has 24 fixed nodes; room for more without an unbounded list.
MAX_NODES: Final = 200
# How finely the drawing's grid cells are found along the rail: far below what a map shows.
DRAWING_STEP_M: Final = 0.05
SIDES: Final = "ABCD"

LatLon = tuple[float, float]
XY = tuple[float, float]

DEFAULT_RAIL_PATH: Final = Path(__file__).with_name("default_rail.json")


class RailConfigError(ValueError):
    """A rail configuration that cannot be used; ``field`` names the offending part."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


@dataclass(frozen=True)
class LocalFrame:
    """Equirectangular projection around a centre: x east, y north, in metres."""

    centre_lat_deg: float
    centre_lon_deg: float

    @property
    def _m_per_deg_lat(self) -> float:
        return math.radians(1.0) * EARTH_RADIUS_M

    @property
    def _m_per_deg_lon(self) -> float:
        return self._m_per_deg_lat * math.cos(math.radians(self.centre_lat_deg))

    def to_xy_m(self, lat_deg: float, lon_deg: float) -> XY:
        return (
            (lon_deg - self.centre_lon_deg) * self._m_per_deg_lon,
            (lat_deg - self.centre_lat_deg) * self._m_per_deg_lat,
        )

    def to_lat_lon(self, x_m: float, y_m: float) -> LatLon:
        return (
            self.centre_lat_deg + y_m / self._m_per_deg_lat,
            self.centre_lon_deg + x_m / self._m_per_deg_lon,
        )


def grid_id(
    lat_deg: float,
    lon_deg: float,
    *,
    centre: LatLon = THESIS_CENTRE,
    grid_points: int = DEFAULT_GRID_POINTS,
) -> str:
    """The thesis position id (``A1`` … ``D<n>``) of a position, by bearing from ``centre``."""
    _check_grid_points(grid_points)
    return _grid_id_xy(*LocalFrame(*centre).to_xy_m(lat_deg, lon_deg), grid_points)


def _grid_id_xy(x_m: float, y_m: float, grid_points: int) -> str:
    """The grid id of a point ``x_m`` east and ``y_m`` north of the centre."""
    bearing_deg = math.degrees(math.atan2(x_m, y_m)) % 360.0  # 0 = north, 90 = east
    side = min(int(bearing_deg // 90.0), 3)  # a bearing of -1e-17 rounds to 360.0
    per_side = grid_points // 4
    within_deg = bearing_deg - 90.0 * side
    index = min(int(within_deg / (90.0 / per_side)), per_side - 1)
    return f"{SIDES[side]}{index + 1}"


def grid_ids(grid_points: int = DEFAULT_GRID_POINTS) -> list[str]:
    """Every id of a grid, clockwise from north: ``A1 … A4, B1 … D4`` for 16 points."""
    _check_grid_points(grid_points)
    per_side = grid_points // 4
    return [f"{side}{k}" for side in SIDES for k in range(1, per_side + 1)]


def _check_grid_points(grid_points: int) -> None:
    if (
        isinstance(grid_points, bool)
        or not isinstance(grid_points, int)
        or not 4 <= grid_points <= MAX_GRID_POINTS
        or grid_points % 4
    ):
        raise RailConfigError(
            "grid_points",
            f"must be a multiple of 4 between 4 and {MAX_GRID_POINTS}, got "
            f"{_describe(grid_points)}",
        )


@dataclass(frozen=True)
class RailPosition:
    """A position projected onto the rail."""

    track_m: float  # along the rail from the origin, clockwise, in [0, length_m)
    lateral_m: float  # distance off the rail, positive outside the loop
    grid_id: str  # the thesis grid id, by bearing from the centre
    edge: int  # index of the polyline edge the position projects onto


class Rail:
    """A closed rail. Build it with :meth:`from_file`, :meth:`from_mapping` or
    :meth:`default`; the constructor checks the same rules and raises
    :class:`RailConfigError` naming the config field at fault."""

    def __init__(
        self,
        points: Sequence[LatLon],
        *,
        centre: LatLon = THESIS_CENTRE,
        origin: LatLon | None = None,
        grid_points: int = DEFAULT_GRID_POINTS,
        name: str = "rail",
        nodes: Sequence[tuple[str, LatLon]] = (),
    ) -> None:
        _check_grid_points(grid_points)
        _check_lat_lon("centre", centre)
        if not 3 <= len(points) <= MAX_POINTS:
            raise RailConfigError(
                "points", f"needs 3 to {MAX_POINTS} points for a closed rail, got {len(points)}"
            )
        for k, point in enumerate(points):
            _check_lat_lon(f"points[{k}]", point)
        if origin is not None:
            _check_lat_lon("origin", origin)
        self.name = name
        self.centre: LatLon = (float(centre[0]), float(centre[1]))
        self.grid_points = grid_points
        self.frame = LocalFrame(*self.centre)

        xy = [self.frame.to_xy_m(lat, lon) for lat, lon in points]
        for k, (x_m, y_m) in enumerate(xy):
            distance_m = math.hypot(x_m, y_m)
            if distance_m > MAX_DISTANCE_FROM_CENTRE_M:
                raise RailConfigError(
                    f"points[{k}]",
                    f"{distance_m / 1000:.1f} km from the centre; the local projection holds "
                    f"within {MAX_DISTANCE_FROM_CENTRE_M / 1000:.0f} km (is centre set?)",
                )
        _check_edges(xy)
        if len(nodes) > MAX_NODES:
            raise RailConfigError("nodes", f"at most {MAX_NODES} fixed nodes, got {len(nodes)}")
        seen: set[str] = set()
        for k, (node_name, place) in enumerate(nodes):
            _check_lat_lon(f"nodes[{k}]", place)
            if node_name in seen:
                raise RailConfigError(f"nodes[{k}].name", f"{node_name!r} is listed twice")
            seen.add(node_name)
            if math.hypot(*self.frame.to_xy_m(*place)) > MAX_DISTANCE_FROM_CENTRE_M:
                raise RailConfigError(
                    f"nodes[{k}]",
                    f"more than {MAX_DISTANCE_FROM_CENTRE_M / 1000:.0f} km from the centre",
                )
        # The fixed nodes' places: drawn with the rail, never used to place the robot.
        self.nodes: list[tuple[str, LatLon]] = [
            (node_name, (float(place[0]), float(place[1]))) for node_name, place in nodes
        ]

        order = list(range(len(xy)))
        if _signed_area_m2(xy) > 0:
            # Counter-clockwise in the file: walk it the other way from the same first point,
            # so that track_m grows clockwise as the agent's direction="cw" says.
            order = [0, *reversed(order[1:])]
        self._xy: list[XY] = [xy[k] for k in order]
        self._file_index: list[int] = order
        self.points: list[LatLon] = [(float(points[k][0]), float(points[k][1])) for k in order]

        self._edge_m: list[float] = []
        self._start_m: list[float] = []
        total_m = 0.0
        for k in range(len(self._xy)):
            (ax, ay), (bx, by) = self._xy[k], self._xy[(k + 1) % len(self._xy)]
            self._start_m.append(total_m)
            self._edge_m.append(math.hypot(bx - ax, by - ay))
            total_m += self._edge_m[-1]
        self.length_m = total_m

        self._origin_m = 0.0
        if origin is not None:
            raw_m, lateral_m, _ = self._project_raw(*self.frame.to_xy_m(*origin))
            if abs(lateral_m) > MAX_ORIGIN_OFFSET_M:
                raise RailConfigError(
                    "origin",
                    f"{abs(lateral_m):.1f} m off the rail; it must be a point on the rail "
                    f"(within {MAX_ORIGIN_OFFSET_M:.0f} m)",
                )
            self._origin_m = raw_m

    # -- building ----------------------------------------------------------------------------

    @classmethod
    def from_mapping(cls, data: object) -> Rail:
        """Build from parsed configuration; any problem is a :class:`RailConfigError`."""
        if not isinstance(data, Mapping):
            raise RailConfigError("rail", f"must be an object, got {_describe(data)}")
        allowed = {"name", "description", "centre", "points", "origin", "grid_points", "nodes"}
        for key in data:
            if key not in allowed:
                raise RailConfigError(
                    _field_name(key), f"unknown field (allowed: {', '.join(sorted(allowed))})"
                )
        name = data.get("name", "rail")
        if not isinstance(name, str) or not name.strip() or len(name) > 200:
            raise RailConfigError(
                "name",
                f"must be a non-empty string of at most 200 characters, got {_describe(name)}",
            )
        description = data.get("description", "")
        if not isinstance(description, str):
            raise RailConfigError("description", f"must be a string, got {_describe(description)}")
        centre = THESIS_CENTRE
        if "centre" in data:
            centre = _parse_lat_lon("centre", data["centre"])
        if "points" not in data:
            raise RailConfigError("points", "is required: the rail's corners, in order")
        raw_points = data["points"]
        if not isinstance(raw_points, list):
            raise RailConfigError("points", f"must be a list, got {_describe(raw_points)}")
        if not 3 <= len(raw_points) <= MAX_POINTS:
            raise RailConfigError(
                "points",
                f"needs 3 to {MAX_POINTS} points for a closed rail, got {len(raw_points)}",
            )
        points = [_parse_lat_lon(f"points[{k}]", p) for k, p in enumerate(raw_points)]
        origin = None
        if "origin" in data:
            origin = _parse_lat_lon("origin", data["origin"])
        grid_points = data.get("grid_points", DEFAULT_GRID_POINTS)
        nodes = _parse_nodes(data.get("nodes", []))
        return cls(
            points, centre=centre, origin=origin, grid_points=grid_points, name=name, nodes=nodes
        )

    @classmethod
    def from_json(cls, text: str | bytes) -> Rail:
        try:
            data = json.loads(text)
        except (ValueError, RecursionError) as exc:  # JSONDecodeError, bad UTF-8, too deep
            raise RailConfigError("json", f"not valid JSON: {_short(str(exc))}") from None
        return cls.from_mapping(data)

    @classmethod
    def from_toml(cls, text: str) -> Rail:
        try:
            data = tomllib.loads(text)
        except (tomllib.TOMLDecodeError, RecursionError) as exc:
            raise RailConfigError("toml", f"not valid TOML: {_short(str(exc))}") from None
        return cls.from_mapping(data)

    @classmethod
    def from_file(cls, path: str | Path) -> Rail:
        """Read a ``.json`` or ``.toml`` rail file (by its suffix)."""
        path = Path(path)
        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise RailConfigError("file", f"cannot read {str(path)!r}: {exc.strerror}") from None
        try:
            if path.suffix.lower() == ".toml":
                return cls.from_toml(raw.decode("utf-8"))
            return cls.from_json(raw)
        except UnicodeDecodeError:
            raise RailConfigError("file", f"{str(path)!r} is not UTF-8 text") from None
        except RailConfigError as exc:
            raise RailConfigError(exc.field, f"{exc.message} (in {path})") from None

    @classmethod
    def configured(cls, path: str | Path | None) -> Rail:
        """The agent's rail: the file ``AGENT_RAIL_FILE`` names, else the default."""
        return cls.from_file(path) if path else cls.default()

    @classmethod
    def default(cls) -> Rail:
        """The rail of ``default_rail.json``: a 30 m square (120 m around) with its corners
        north, east, south and west of the thesis centre. The simulator's default too."""
        return cls.from_file(DEFAULT_RAIL_PATH)

    # -- using -------------------------------------------------------------------------------

    def project(self, lat_deg: float, lon_deg: float) -> RailPosition:
        """Project a GPS position onto the rail (the nearest point of the polyline)."""
        raw_m, lateral_m, edge = self._project_raw(*self.frame.to_xy_m(lat_deg, lon_deg))
        return RailPosition(
            track_m=self.wrap(raw_m - self._origin_m),
            lateral_m=lateral_m,
            grid_id=self.grid_id(lat_deg, lon_deg),
            edge=edge,
        )

    def point_at(self, track_m: float) -> LatLon:
        """The GPS position of the rail at ``track_m`` (any real number: it wraps)."""
        return self.frame.to_lat_lon(*self.xy_at(track_m))

    def xy_at(self, track_m: float) -> XY:
        """The rail at ``track_m`` (any real number: it wraps) in metres east and north of
        the centre: the simulator adds its GPS noise in this frame."""
        raw_m = self.wrap(track_m + self._origin_m)
        edge = max(bisect.bisect_right(self._start_m, raw_m) - 1, 0)
        (ax, ay), (bx, by) = self._xy[edge], self._xy[(edge + 1) % len(self._xy)]
        fraction = (raw_m - self._start_m[edge]) / self._edge_m[edge]
        return ax + fraction * (bx - ax), ay + fraction * (by - ay)

    def side_at(self, track_m: float) -> str:
        """The thesis side (``A`` … ``D``) of the rail at ``track_m``: the letter of its
        grid id, so the simulator's logs name sides as the agent's samples do."""
        return _grid_id_xy(*self.xy_at(track_m), self.grid_points)[0]

    def wrap(self, track_m: float) -> float:
        """``track_m`` brought into ``[0, length_m)``, e.g. a simulated odometer reading."""
        wrapped_m = track_m % self.length_m
        # Float modulo can land on length_m itself for values just below a multiple of it.
        return 0.0 if wrapped_m >= self.length_m else wrapped_m

    def grid_id(self, lat_deg: float, lon_deg: float) -> str:
        return grid_id(lat_deg, lon_deg, centre=self.centre, grid_points=self.grid_points)

    @property
    def grid_ids(self) -> list[str]:
        return grid_ids(self.grid_points)

    def drawing(self) -> dict[str, object]:
        """What a map of the roof needs, in metres east (``x_m``) and north (``y_m``) of the
        centre: the corners clockwise with the ``track_m`` of each, the grid cells as spans
        of ``track_m`` (a cell the origin cuts is two spans), and the fixed nodes' places.
        A page places the robot by ``track_m`` alone, with no projection of its own."""
        count = len(self._xy)
        points = [
            {
                "x_m": round(x_m, 3),
                "y_m": round(y_m, 3),
                "track_m": round(self.wrap(self._start_m[k] - self._origin_m), 3),
            }
            for k, (x_m, y_m) in enumerate(self._xy)
        ]
        steps = max(int(self.length_m / DRAWING_STEP_M), count)
        cells: list[dict[str, object]] = []
        for k in range(steps):
            at_m = self.length_m * k / steps
            cell = _grid_id_xy(*self.xy_at(at_m), self.grid_points)
            if cells and cells[-1]["id"] == cell:
                cells[-1]["to_m"] = round(self.length_m * (k + 1) / steps, 3)
            else:
                cells.append(
                    {
                        "id": cell,
                        "from_m": round(at_m, 3),
                        "to_m": round(self.length_m * (k + 1) / steps, 3),
                    }
                )
        return {
            "name": self.name,
            "length_m": self.length_m,
            "centre": {"lat": self.centre[0], "lon": self.centre[1]},
            "grid_points": self.grid_points,
            "origin": dict(
                zip(("x_m", "y_m"), (round(v, 3) for v in self.xy_at(0.0)), strict=True)
            ),
            "points": points,
            "cells": cells,
            "nodes": [
                {
                    "name": node_name,
                    "lat": lat,
                    "lon": lon,
                    **dict(
                        zip(
                            ("x_m", "y_m"),
                            (round(v, 3) for v in self.frame.to_xy_m(lat, lon)),
                            strict=True,
                        )
                    ),
                }
                for node_name, (lat, lon) in self.nodes
            ],
        }

    def _project_raw(self, x_m: float, y_m: float) -> tuple[float, float, int]:
        """(distance along the polyline from its first point, signed offset, edge)."""
        best: tuple[float, float, float, int] | None = None  # distance², along, lateral, edge
        count = len(self._xy)
        for k in range(count):
            (ax, ay), (bx, by) = self._xy[k], self._xy[(k + 1) % count]
            dx, dy = bx - ax, by - ay
            length_m = self._edge_m[k]
            fraction = ((x_m - ax) * dx + (y_m - ay) * dy) / (length_m * length_m)
            fraction = min(max(fraction, 0.0), 1.0)
            px, py = ax + fraction * dx, ay + fraction * dy
            distance2 = (x_m - px) ** 2 + (y_m - py) ** 2
            if best is None or distance2 < best[0]:
                # Left of a clockwise walk is outside the loop: positive lateral offset.
                cross = dx * (y_m - ay) - dy * (x_m - ax)
                lateral_m = math.copysign(math.sqrt(distance2), cross) if cross else 0.0
                best = (distance2, self._start_m[k] + fraction * length_m, lateral_m, k)
        assert best is not None
        return best[1], best[2], best[3]


# -- checks -----------------------------------------------------------------------------------


def _describe(value: object) -> str:
    """A short description of a config value for an error message (never a huge repr)."""
    if value is None or isinstance(value, bool | int | float):
        return _short(repr(value))
    if isinstance(value, str):
        return f"the string {_short(repr(value))}"
    return f"a {type(value).__name__}"


def _short(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _field_name(key: object) -> str:
    if isinstance(key, str) and key.isidentifier():
        return _short(key, 40)
    return _short(repr(key), 40)  # quoted, so an empty or odd key is still visible


def _parse_number(field: str, value: object, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise RailConfigError(field, f"must be a number, got {_describe(value)}")
    # Compared before float(): a huge JSON integer would overflow the conversion.
    if not (low <= value <= high) or (isinstance(value, float) and not math.isfinite(value)):
        raise RailConfigError(
            field, f"must be between {low:g} and {high:g}, got {_describe(value)}"
        )
    return float(value)


def _parse_lat_lon(field: str, value: object) -> LatLon:
    if not isinstance(value, Mapping):
        raise RailConfigError(field, f"must be an object {{lat, lon}}, got {_describe(value)}")
    for key in value:
        if key not in ("lat", "lon"):
            raise RailConfigError(f"{field}.{_field_name(key)}", "unknown field (only lat, lon)")
    for key in ("lat", "lon"):
        if key not in value:
            raise RailConfigError(f"{field}.{key}", "is required")
    return (
        _parse_number(f"{field}.lat", value["lat"], -90.0, 90.0),
        _parse_number(f"{field}.lon", value["lon"], -180.0, 180.0),
    )


def _parse_nodes(value: object) -> list[tuple[str, LatLon]]:
    if not isinstance(value, list):
        raise RailConfigError("nodes", f"must be a list, got {_describe(value)}")
    if len(value) > MAX_NODES:
        raise RailConfigError("nodes", f"at most {MAX_NODES} fixed nodes, got {len(value)}")
    nodes = []
    for k, item in enumerate(value):
        field = f"nodes[{k}]"
        if not isinstance(item, Mapping):
            raise RailConfigError(
                field, f"must be an object {{name, lat, lon}}, got {_describe(item)}"
            )
        for key in item:
            if key not in ("name", "lat", "lon"):
                raise RailConfigError(
                    f"{field}.{_field_name(key)}", "unknown field (only name, lat, lon)"
                )
        name = item.get("name")
        if not isinstance(name, str) or not name.strip() or len(name) > 64:
            raise RailConfigError(
                f"{field}.name",
                f"must be a non-empty string of at most 64 characters, got {_describe(name)}",
            )
        place = _parse_lat_lon(field, {k: v for k, v in item.items() if k != "name"})
        nodes.append((name, place))
    return nodes


def _check_lat_lon(field: str, point: object) -> None:
    """The same rules for points given in code as for points read from a file."""
    if not isinstance(point, Sequence) or isinstance(point, str) or len(point) != 2:
        raise RailConfigError(field, f"must be a (lat, lon) pair, got {_describe(point)}")
    _parse_number(f"{field}.lat", point[0], -90.0, 90.0)
    _parse_number(f"{field}.lon", point[1], -180.0, 180.0)


def _signed_area_m2(xy: Sequence[XY]) -> float:
    """Shoelace area: positive for a counter-clockwise loop (x east, y north)."""
    count = len(xy)
    return 0.5 * sum(
        xy[k][0] * xy[(k + 1) % count][1] - xy[(k + 1) % count][0] * xy[k][1] for k in range(count)
    )


def _point_segment_m(p: XY, a: XY, b: XY) -> float:
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy
    fraction = 0.0
    if length2 > 0:
        fraction = min(max(((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / length2, 0.0), 1.0)
    return math.hypot(p[0] - (a[0] + fraction * dx), p[1] - (a[1] + fraction * dy))


def _cross(o: XY, a: XY, b: XY) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _segments_m(a: XY, b: XY, c: XY, d: XY) -> float:
    """Distance between segments ab and cd (0 when they cross)."""
    d1, d2 = _cross(c, d, a), _cross(c, d, b)
    d3, d4 = _cross(a, b, c), _cross(a, b, d)
    if d1 * d2 < 0 and d3 * d4 < 0:  # each segment's ends lie on both sides of the other
        return 0.0
    return min(
        _point_segment_m(a, c, d),
        _point_segment_m(b, c, d),
        _point_segment_m(c, a, b),
        _point_segment_m(d, a, b),
    )


def _check_edges(xy: Sequence[XY]) -> None:
    count = len(xy)
    for k in range(count):
        j = (k + 1) % count
        if math.dist(xy[k], xy[j]) < MIN_EDGE_M:
            # Name the later of the two: for a repeated first point that is the last one.
            later, earlier = (j, k) if j else (k, j)
            raise RailConfigError(
                f"points[{later}]",
                f"zero-length edge: the same point as points[{earlier}] (closer than "
                f"{MIN_EDGE_M * 100:.0f} cm); the rail closes by itself, do not repeat the "
                "first point at the end",
            )
    for k in range(count):
        a, b = xy[k], xy[(k + 1) % count]
        for j in range(k + 1, count):
            c, d = xy[j], xy[(j + 1) % count]
            if j == k + 1 or (k == 0 and j == count - 1):
                # Neighbours share a corner; they overlap only if one doubles back on the
                # other (a turn of 180°).
                if j == k + 1:
                    shared, before, after = b, a, d
                else:
                    shared, before, after = a, b, c
                if (
                    _point_segment_m(after, before, shared) < MIN_EDGE_M
                    or _point_segment_m(before, shared, after) < MIN_EDGE_M
                ):
                    raise RailConfigError(
                        "points",
                        f"the edges at points[{_corner(k, j, count)}] double back on each "
                        "other (a 180° turn): the rail overlaps itself",
                    )
                continue
            if _segments_m(a, b, c, d) < MIN_EDGE_M:
                raise RailConfigError(
                    "points",
                    f"edge points[{k}]→points[{(k + 1) % count}] crosses or touches edge "
                    f"points[{j}]→points[{(j + 1) % count}]: the rail must not overlap itself",
                )


def _corner(k: int, j: int, count: int) -> int:
    return (k + 1) % count if j == k + 1 else 0
