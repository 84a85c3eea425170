"""The rail: a closed polyline around the building, from configuration, never from code.

Positions on the rail are metres along the track (``track_m``) from the first vertex,
increasing clockwise (CW, the protocol's direction 1) when the vertices are listed clockwise
as seen from above. Geometry is computed in a local east/north plane around a centre point
(equirectangular projection: over a 100 m roof its error is far below a millimetre).

The default is the thesis's roof: the building's corners point at the four cardinal points
(thesis §3.4), so the default rail is a 30 m square (120 m around) with its corners north,
east, south and west of the building centre (40.634172, -8.660015), sides A = N-E, B = E-S,
C = S-W, D = W-N.
"""

from __future__ import annotations

import bisect
import json
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

EARTH_RADIUS_M: Final = 6_371_008.8  # mean radius (IUGG)
BUILDING_CENTRE: Final = (40.634172, -8.660015)
DEFAULT_SIDE_M: Final = 30.0
#: Shorter segments are almost certainly a typo (a repeated vertex).
MIN_SEGMENT_M: Final = 0.01


class RailConfigError(ValueError):
    """The rail configuration does not describe a usable closed rail; the message names the
    offending field."""


@dataclass(frozen=True)
class RailGeometry:
    """A closed rail. ``vertices_m`` are (east, north) metres from the centre, in track order."""

    centre_lat_deg: float
    centre_lon_deg: float
    vertices_m: tuple[tuple[float, float], ...]
    side_names: tuple[str, ...] = ()
    _cumulative_m: tuple[float, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        _check_geometry(self.centre_lat_deg, self.centre_lon_deg, self.vertices_m, self.side_names)
        cumulative = [0.0]
        for (e0, n0), (e1, n1) in self._segments():
            cumulative.append(cumulative[-1] + math.hypot(e1 - e0, n1 - n0))
        object.__setattr__(self, "_cumulative_m", tuple(cumulative))

    # --- construction ---------------------------------------------------------------------------

    @classmethod
    def default(cls) -> RailGeometry:
        half_diagonal_m = DEFAULT_SIDE_M / math.sqrt(2.0)
        return cls(
            centre_lat_deg=BUILDING_CENTRE[0],
            centre_lon_deg=BUILDING_CENTRE[1],
            vertices_m=(
                (0.0, half_diagonal_m),  # north corner: track 0
                (half_diagonal_m, 0.0),  # east
                (0.0, -half_diagonal_m),  # south
                (-half_diagonal_m, 0.0),  # west
            ),
            side_names=("A", "B", "C", "D"),
        )

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], *, where: str = "rail") -> RailGeometry:
        """From a ``[rail]`` table: ``vertices_m`` = [[east, north], ...] around ``centre`` =
        [lat, lon] (default: the building centre), or ``vertices`` = [[lat, lon], ...]
        (centre: their mean unless given); optional ``sides`` = one name per segment."""
        if not isinstance(data, Mapping):
            raise RailConfigError(f"{where} must be a table")
        known = {"centre", "vertices", "vertices_m", "sides"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise RailConfigError(
                f"{where}: unknown key(s) {', '.join(unknown)}"
                f" (expected {', '.join(sorted(known))})"
            )
        if ("vertices" in data) == ("vertices_m" in data):
            raise RailConfigError(f"{where}: give exactly one of vertices (lat, lon) or vertices_m")
        sides = data.get("sides", ())
        if not isinstance(sides, Sequence) or isinstance(sides, str):
            raise RailConfigError(f"{where}.sides must be a list of names")
        side_names = tuple(sides)
        if "vertices_m" in data:
            centre = _pair(data.get("centre", BUILDING_CENTRE), f"{where}.centre")
            vertices = tuple(
                _pair(v, f"{where}.vertices_m[{i}]")
                for i, v in enumerate(_list(data["vertices_m"], f"{where}.vertices_m"))
            )
            return _build(cls, centre, vertices, side_names, where)
        lat_lon = tuple(
            _pair(v, f"{where}.vertices[{i}]")
            for i, v in enumerate(_list(data["vertices"], f"{where}.vertices"))
        )
        for i, (lat, lon) in enumerate(lat_lon):
            _check_lat_lon(lat, lon, f"{where}.vertices[{i}]")
        if "centre" in data:
            centre = _pair(data["centre"], f"{where}.centre")
        else:
            centre = (
                sum(p[0] for p in lat_lon) / max(1, len(lat_lon)),
                sum(p[1] for p in lat_lon) / max(1, len(lat_lon)),
            )
        _check_lat_lon(*centre, f"{where}.centre")
        vertices = tuple(_to_local(lat, lon, centre[0], centre[1]) for lat, lon in lat_lon)
        return _build(cls, centre, vertices, side_names, where)

    @classmethod
    def load(cls, path: Path | str) -> RailGeometry:
        """A JSON or TOML file holding a ``rail`` table (or being one)."""
        data = load_config_file(path)
        table = data.get("rail", data)
        return cls.from_mapping(table, where=f"{path}: rail")

    def to_mapping(self) -> dict[str, Any]:
        return {
            "centre": [self.centre_lat_deg, self.centre_lon_deg],
            "vertices_m": [list(v) for v in self.vertices_m],
            "sides": list(self.side_names),
        }

    # --- geometry ------------------------------------------------------------------------------

    def _segments(self) -> list[tuple[tuple[float, float], tuple[float, float]]]:
        v = self.vertices_m
        return [(v[i], v[(i + 1) % len(v)]) for i in range(len(v))]

    @property
    def length_m(self) -> float:
        return self._cumulative_m[-1]

    def wrap(self, track_m: float) -> float:
        wrapped = track_m % self.length_m
        return 0.0 if math.isclose(wrapped, self.length_m) else wrapped

    def _locate(self, track_m: float) -> tuple[int, float]:
        """Segment index and metres into it."""
        s = self.wrap(track_m)
        index = bisect.bisect_right(self._cumulative_m, s) - 1
        index = min(max(index, 0), len(self.vertices_m) - 1)
        return index, s - self._cumulative_m[index]

    def point_at(self, track_m: float) -> tuple[float, float]:
        """(east, north) metres from the centre."""
        index, into_m = self._locate(track_m)
        (e0, n0), (e1, n1) = self._segments()[index]
        length = self._cumulative_m[index + 1] - self._cumulative_m[index]
        f = into_m / length
        return e0 + f * (e1 - e0), n0 + f * (n1 - n0)

    def heading_at(self, track_m: float) -> tuple[float, float]:
        """Unit (east, north) vector of increasing ``track_m`` (clockwise travel)."""
        index, _ = self._locate(track_m)
        (e0, n0), (e1, n1) = self._segments()[index]
        length = math.hypot(e1 - e0, n1 - n0)
        return (e1 - e0) / length, (n1 - n0) / length

    def lat_lon_at(self, track_m: float) -> tuple[float, float]:
        return self.to_lat_lon(*self.point_at(track_m))

    def to_lat_lon(self, east_m: float, north_m: float) -> tuple[float, float]:
        lat = self.centre_lat_deg + math.degrees(north_m / EARTH_RADIUS_M)
        lon = self.centre_lon_deg + math.degrees(
            east_m / (EARTH_RADIUS_M * math.cos(math.radians(self.centre_lat_deg)))
        )
        return lat, lon

    def to_local(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        return _to_local(lat_deg, lon_deg, self.centre_lat_deg, self.centre_lon_deg)

    def project(self, lat_deg: float, lon_deg: float) -> float:
        """``track_m`` of the rail point nearest to a position (a GPS fix)."""
        east, north = self.to_local(lat_deg, lon_deg)
        best_m, best_d2 = 0.0, math.inf
        for i, ((e0, n0), (e1, n1)) in enumerate(self._segments()):
            de, dn = e1 - e0, n1 - n0
            length2 = de * de + dn * dn
            f = ((east - e0) * de + (north - n0) * dn) / length2
            f = min(1.0, max(0.0, f))
            pe, pn = e0 + f * de, n0 + f * dn
            d2 = (east - pe) ** 2 + (north - pn) ** 2
            if d2 < best_d2:
                best_d2 = d2
                best_m = self._cumulative_m[i] + f * math.sqrt(length2)
        return self.wrap(best_m)

    def side_at(self, track_m: float) -> str:
        """The side's name (``A``...) or its 1-based number when the sides are unnamed."""
        index, _ = self._locate(track_m)
        return self.side_names[index] if self.side_names else str(index + 1)


# --- configuration helpers -------------------------------------------------------------------


def load_config_file(path: Path | str) -> dict[str, Any]:
    """A ``.json`` or ``.toml`` file as a dict; errors name the file."""
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except OSError as error:
        raise RailConfigError(f"{file}: cannot read: {error.strerror or error}") from error
    try:
        if file.suffix.lower() == ".toml":
            data: Any = tomllib.loads(text)
        elif file.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            raise RailConfigError(f"{file}: use a .json or .toml file")
    except tomllib.TOMLDecodeError as error:
        raise RailConfigError(f"{file}: not valid TOML: {error}") from error
    except json.JSONDecodeError as error:
        raise RailConfigError(f"{file}: not valid JSON: {error}") from error
    if not isinstance(data, dict):
        raise RailConfigError(f"{file}: the top level must be a table/object")
    return data


def _to_local(lat: float, lon: float, lat0: float, lon0: float) -> tuple[float, float]:
    north = math.radians(lat - lat0) * EARTH_RADIUS_M
    east = math.radians(lon - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
    return east, north


def _build(
    cls: type[RailGeometry],
    centre: tuple[float, float],
    vertices: tuple[tuple[float, float], ...],
    sides: tuple[Any, ...],
    where: str,
) -> RailGeometry:
    try:
        return cls(centre[0], centre[1], vertices, sides)
    except RailConfigError as error:
        raise RailConfigError(f"{where}: {error}") from None


def _list(value: Any, where: str) -> list[Any]:
    if not isinstance(value, list | tuple):
        raise RailConfigError(f"{where} must be a list")
    return list(value)


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise RailConfigError(f"{where} must be a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise RailConfigError(f"{where} must be finite, got {value!r}")
    return number


def _pair(value: Any, where: str) -> tuple[float, float]:
    if not isinstance(value, list | tuple) or len(value) != 2:
        raise RailConfigError(f"{where} must be a pair of numbers, got {value!r}")
    return _number(value[0], f"{where}[0]"), _number(value[1], f"{where}[1]")


def _check_lat_lon(lat: float, lon: float, where: str) -> None:
    if not -90.0 <= lat <= 90.0:
        raise RailConfigError(f"{where}: latitude {lat} outside -90..90")
    if not -180.0 <= lon <= 180.0:
        raise RailConfigError(f"{where}: longitude {lon} outside -180..180")


def _cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _segments_cross(
    p1: tuple[float, float],
    p2: tuple[float, float],
    q1: tuple[float, float],
    q2: tuple[float, float],
) -> bool:
    d1, d2 = _cross(q1, q2, p1), _cross(q1, q2, p2)
    d3, d4 = _cross(p1, p2, q1), _cross(p1, p2, q2)
    return d1 * d2 < 0 and d3 * d4 < 0


def _check_geometry(
    lat0: float,
    lon0: float,
    vertices: Sequence[tuple[float, float]],
    sides: Sequence[Any],
) -> None:
    for value, name in ((lat0, "centre latitude"), (lon0, "centre longitude")):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise RailConfigError(f"{name} must be a number")
    _check_lat_lon(lat0, lon0, "centre")
    if len(vertices) < 3:
        raise RailConfigError(f"a closed rail needs at least 3 vertices, got {len(vertices)}")
    for i, vertex in enumerate(vertices):
        if len(vertex) != 2 or not all(math.isfinite(float(c)) for c in vertex):
            raise RailConfigError(f"vertex {i} must be two finite numbers, got {vertex!r}")
        if max(abs(vertex[0]), abs(vertex[1])) > 50_000.0:
            raise RailConfigError(f"vertex {i} is more than 50 km from the centre: {vertex!r}")
    n = len(vertices)
    segments = [(vertices[i], vertices[(i + 1) % n]) for i in range(n)]
    perimeter_m = 0.0
    for i, (a, b) in enumerate(segments):
        length = math.hypot(b[0] - a[0], b[1] - a[1])
        if length < MIN_SEGMENT_M:
            raise RailConfigError(
                f"segment {i} (vertex {i} to {(i + 1) % n}) is {length:.4f} m long: "
                "repeated vertex? (do not repeat the first vertex at the end:"
                " the rail closes itself)"
            )
        perimeter_m += length
    if not 1.0 <= perimeter_m <= 100_000.0:
        raise RailConfigError(f"rail length {perimeter_m:.1f} m not in 1..100000 m")
    for i in range(n):
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue  # neighbours share a vertex
            if _segments_cross(*segments[i], *segments[j]):
                raise RailConfigError(f"segments {i} and {j} cross: the rail must not cross itself")
    if sides:
        if len(sides) != n:
            raise RailConfigError(f"sides names {len(sides)} sides, the rail has {n} segments")
        if not all(isinstance(s, str) and s.strip() for s in sides):
            raise RailConfigError("every side name must be a non-empty string")
        if len(set(sides)) != len(sides):
            raise RailConfigError("side names must be unique")
