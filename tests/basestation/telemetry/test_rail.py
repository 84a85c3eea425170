"""Rail geometry: configuration checks, projection onto the polyline, thesis grid ids."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from basestation.telemetry import (
    DEFAULT_RAIL_PATH,
    THESIS_CENTRE,
    LocalFrame,
    Rail,
    RailConfigError,
    grid_id,
    grid_ids,
)

CENTRE = LocalFrame(*THESIS_CENTRE)


def at(east_m: float, north_m: float) -> tuple[float, float]:
    """The (lat, lon) of a point ``east_m``, ``north_m`` from the thesis centre."""
    return CENTRE.to_lat_lon(east_m, north_m)


def point(east_m: float, north_m: float) -> dict[str, float]:
    lat, lon = at(east_m, north_m)
    return {"lat": lat, "lon": lon}


def square(side_m: float = 40.0, *, clockwise: bool = True) -> list[dict[str, float]]:
    """An axis-aligned square around the centre, from its north-west corner."""
    h = side_m / 2
    corners = [(-h, h), (h, h), (h, -h), (-h, -h)]  # NW, NE, SE, SW: clockwise
    if not clockwise:
        corners = [corners[0], *reversed(corners[1:])]
    return [point(x, y) for x, y in corners]


def config(**overrides: Any) -> dict[str, Any]:
    body: dict[str, Any] = {"name": "test rail", "points": square()}
    body.update(overrides)
    return body


def circular_gap_m(a_m: float, b_m: float, length_m: float) -> float:
    gap_m = abs(a_m - b_m) % length_m
    return min(gap_m, length_m - gap_m)


# -- the default rail ---------------------------------------------------------------------------


def test_the_default_rail_is_a_120_m_loop_with_corners_at_the_cardinal_points() -> None:
    rail = Rail.default()
    assert rail.length_m == pytest.approx(120.0, abs=0.05)
    assert rail.centre == THESIS_CENTRE
    assert rail.grid_points == 16
    north, east, south, west = (CENTRE.to_xy_m(*p) for p in rail.points)
    radius_m = 30 / math.sqrt(2)
    assert north == pytest.approx((0.0, radius_m), abs=0.02)
    assert east == pytest.approx((radius_m, 0.0), abs=0.02)
    assert south == pytest.approx((0.0, -radius_m), abs=0.02)
    assert west == pytest.approx((-radius_m, 0.0), abs=0.02)


def test_on_the_default_rail_the_sides_are_the_thesis_sides() -> None:
    rail = Rail.default()
    side_m = rail.length_m / 4
    # track_m starts at the north corner and runs clockwise: N-E is side A, and so on.
    for side_index, side in enumerate("ABCD"):
        for k in range(4):
            # The middle of the k-th quarter of the side's angle: tan() of the bearing.
            along = (
                side_index * side_m
                + side_m * (1 + math.tan(math.radians(-45 + 22.5 * k + 11.25))) / 2
            )
            lat, lon = rail.point_at(along)
            assert rail.project(lat, lon).grid_id == f"{side}{k + 1}"


def test_the_default_rail_walks_the_cardinal_corners_clockwise_from_north() -> None:
    rail = Rail.default()
    lat0, lon0 = THESIS_CENTRE
    quarter_m = rail.length_m / 4
    north, east, south, west = (rail.point_at(k * quarter_m) for k in range(4))
    assert north[0] > lat0
    assert north[1] == pytest.approx(lon0, abs=1e-7)
    assert east[0] == pytest.approx(lat0, abs=1e-7)
    assert east[1] > lon0
    assert south[0] < lat0
    assert south[1] == pytest.approx(lon0, abs=1e-7)
    assert west[0] == pytest.approx(lat0, abs=1e-7)
    assert west[1] < lon0
    assert [rail.side_at(k * quarter_m + 1.0) for k in range(4)] == ["A", "B", "C", "D"]
    for track_m in (0.0, 7.5, 29.99, 45.0, 119.0):
        assert rail.project(*rail.point_at(track_m)).track_m == pytest.approx(track_m, abs=1e-6)


def test_the_default_rail_file_is_shipped_next_to_the_code() -> None:
    assert DEFAULT_RAIL_PATH.name == "default_rail.json"
    assert Rail.from_file(DEFAULT_RAIL_PATH).points == Rail.default().points


# -- grid ids -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("bearing_deg", "expected"),
    [
        (0.0, "A1"),
        (22.4, "A1"),
        (22.6, "A2"),
        (45.1, "A3"),
        (89.9, "A4"),
        (90.0, "B1"),
        (135.1, "B3"),
        (180.0, "C1"),
        (269.9, "C4"),
        (270.1, "D1"),
        (359.9, "D4"),
    ],
)
def test_the_grid_id_comes_from_the_bearing_from_the_centre(
    bearing_deg: float, expected: str
) -> None:
    lat, lon = at(
        50 * math.sin(math.radians(bearing_deg)), 50 * math.cos(math.radians(bearing_deg))
    )
    assert grid_id(lat, lon) == expected


def test_the_number_of_grid_points_per_lap_is_configurable() -> None:
    assert grid_ids(16) == [f"{s}{k}" for s in "ABCD" for k in range(1, 5)]
    assert grid_ids(8) == ["A1", "A2", "B1", "B2", "C1", "C2", "D1", "D2"]
    lat, lon = at(30.0, 10.0)  # bearing 71.6°: the last of two, the fourth of four
    assert grid_id(lat, lon, grid_points=8) == "A2"
    assert grid_id(lat, lon, grid_points=16) == "A4"
    assert grid_id(lat, lon, grid_points=4) == "A1"
    rail = Rail.from_mapping(config(grid_points=8))
    assert rail.grid_ids == grid_ids(8)
    assert rail.project(lat, lon).grid_id == "A2"


# -- projection ---------------------------------------------------------------------------------


def test_a_rail_from_latitudes_and_longitudes_measures_its_edges_on_the_earth() -> None:
    corners = [(40.6342, -8.6601), (40.6342, -8.6599), (40.6340, -8.6599), (40.6340, -8.6601)]
    rail = Rail.from_mapping({"points": [{"lat": lat, "lon": lon} for lat, lon in corners]})
    # Independent of the code's frame: arcs on a sphere of the mean Earth radius.
    side_ns_m = math.radians(0.0002) * 6_371_008.8
    side_ew_m = side_ns_m * math.cos(math.radians(THESIS_CENTRE[0]))
    assert rail.length_m == pytest.approx(2 * (side_ns_m + side_ew_m), rel=1e-5)
    assert rail.point_at(0.0) == pytest.approx(corners[0])
    assert rail.point_at(side_ew_m) == pytest.approx(corners[1])


def test_wrap_brings_any_track_position_into_one_lap() -> None:
    rail = Rail.default()
    assert rail.wrap(rail.length_m + 1.0) == pytest.approx(1.0)
    assert rail.wrap(-1.0) == pytest.approx(rail.length_m - 1.0)
    assert rail.wrap(-3 * rail.length_m) == pytest.approx(0.0, abs=1e-9)
    assert rail.wrap(5.0) == 5.0
    # Just below a whole lap, float modulo gives length_m itself; that is position 0.
    assert rail.wrap(-1e-300) == 0.0
    assert 0.0 <= rail.wrap(math.nextafter(rail.length_m, 0.0)) < rail.length_m


def test_xy_at_is_the_rail_in_metres_around_the_centre_walked_clockwise() -> None:
    for rail in (
        Rail.from_mapping(config()),
        Rail.from_mapping(config(points=square(clockwise=False))),
    ):
        assert rail.xy_at(0.0) == pytest.approx((-20.0, 20.0), abs=1e-6)  # NW, the origin
        assert rail.xy_at(20.0) == pytest.approx((0.0, 20.0), abs=1e-6)  # east along the N side
        assert rail.xy_at(60.0) == pytest.approx((20.0, 0.0), abs=1e-6)  # south along the E side
        assert rail.xy_at(-10.0) == pytest.approx((-20.0, 10.0), abs=1e-6)  # wraps
        for track_m in (0.0, 33.3, 101.0, 159.9):
            assert rail.frame.to_lat_lon(*rail.xy_at(track_m)) == pytest.approx(
                rail.point_at(track_m)
            )


def test_xy_at_counts_from_the_origin() -> None:
    rail = Rail.from_mapping(config(origin=point(0.0, 20.0)))
    assert rail.xy_at(0.0) == pytest.approx((0.0, 20.0), abs=1e-6)
    assert rail.xy_at(20.0) == pytest.approx((20.0, 20.0), abs=1e-6)


@pytest.mark.parametrize(
    ("track_m", "side"),
    [(10.0, "D"), (30.0, "A"), (50.0, "A"), (70.0, "B"), (90.0, "B"), (110.0, "C"), (150.0, "D")],
)
def test_the_side_at_a_track_position_is_the_letter_of_its_grid_id(
    track_m: float, side: str
) -> None:
    rail = Rail.from_mapping(config())  # from the NW corner: the sides are cut by bearing
    assert rail.side_at(track_m) == side
    assert rail.project(*rail.point_at(track_m)).grid_id[0] == side


def test_track_grows_clockwise_from_the_origin_whatever_the_file_order() -> None:
    forward = Rail.from_mapping(config())
    backward = Rail.from_mapping(config(points=square(clockwise=False)))
    assert forward.length_m == pytest.approx(160.0, abs=1e-6)
    for rail in (forward, backward):
        assert rail.project(*at(-20.0, 20.0)).track_m == pytest.approx(0.0, abs=1e-6)  # NW
        assert rail.project(*at(0.0, 20.0)).track_m == pytest.approx(20.0, abs=1e-6)  # N side
        assert rail.project(*at(20.0, 0.0)).track_m == pytest.approx(60.0, abs=1e-6)  # E side
        assert rail.project(*at(-20.0, 10.0)).track_m == pytest.approx(150.0, abs=1e-6)


def test_the_origin_sets_where_track_m_is_zero() -> None:
    rail = Rail.from_mapping(config(origin=point(0.0, 20.0)))
    assert rail.project(*at(0.0, 20.0)).track_m == pytest.approx(0.0, abs=1e-6)
    assert rail.project(*at(20.0, 20.0)).track_m == pytest.approx(20.0, abs=1e-6)
    assert rail.project(*at(-10.0, 20.0)).track_m == pytest.approx(150.0, abs=1e-6)
    assert rail.point_at(0.0) == pytest.approx(at(0.0, 20.0))
    assert rail.point_at(-10.0) == pytest.approx(at(-10.0, 20.0))  # wraps


def test_the_lateral_offset_is_positive_outside_the_loop() -> None:
    rail = Rail.from_mapping(config())
    outside = rail.project(*at(0.0, 23.0))
    inside = rail.project(*at(0.0, 18.5))
    assert outside.track_m == pytest.approx(20.0, abs=1e-6)
    assert outside.lateral_m == pytest.approx(3.0, abs=1e-6)
    assert inside.track_m == pytest.approx(20.0, abs=1e-6)
    assert inside.lateral_m == pytest.approx(-1.5, abs=1e-6)
    assert outside.edge == inside.edge == 0


@st.composite
def star_rails(draw: st.DrawFn) -> Rail:
    """Random simple polygons: corners at increasing angles round the centre."""
    count = draw(st.integers(min_value=3, max_value=12))
    angles = sorted(
        draw(
            st.lists(
                st.floats(min_value=0.0, max_value=2 * math.pi, exclude_max=True),
                min_size=count,
                max_size=count,
                unique=True,
            )
        )
    )
    radii = draw(st.lists(st.floats(1.0, 200.0), min_size=count, max_size=count))
    points = [at(r * math.cos(a), r * math.sin(a)) for a, r in zip(angles, radii, strict=True)]
    try:
        return Rail(points)
    except RailConfigError:
        assume(False)  # too thin to be a rail (edges closer than 1 cm)
        raise


@given(rail=star_rails(), fraction=st.floats(min_value=0.0, max_value=1.0, exclude_max=True))
def test_a_point_on_the_rail_projects_back_onto_itself(rail: Rail, fraction: float) -> None:
    track_m = fraction * rail.length_m
    position = rail.project(*rail.point_at(track_m))
    assert 0.0 <= position.track_m < rail.length_m
    assert circular_gap_m(position.track_m, track_m, rail.length_m) < 0.01
    assert abs(position.lateral_m) < 0.01


@given(track_m=st.floats(min_value=-1000.0, max_value=1000.0))
def test_every_point_of_the_default_rail_projects_back_within_a_centimetre(track_m: float) -> None:
    rail = Rail.default()
    position = rail.project(*rail.point_at(track_m))
    assert circular_gap_m(position.track_m, track_m, rail.length_m) < 0.01


# -- configuration errors -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("body", "field", "words"),
    [
        ([1, 2, 3], "rail", "object"),
        ({"name": "x"}, "points", "required"),
        (config(points=square()[:2]), "points", "3 to"),
        (config(points="NW NE SE"), "points", "list"),
        (config(points=[*square()[:3], [40.6, -8.66]]), "points[3]", "object"),
        (config(points=[*square()[:3], {"lat": "40.6", "lon": -8.66}]), "points[3].lat", "number"),
        (config(points=[*square()[:3], {"lat": True, "lon": -8.66}]), "points[3].lat", "number"),
        (config(points=[*square()[:3], {"lat": 40.6}]), "points[3].lon", "required"),
        (config(points=[*square()[:3], {"lat": 40.6, "lng": 1}]), "points[3].lng", "unknown"),
        (config(points=[*square()[:3], {"lat": 91, "lon": 0}]), "points[3].lat", "between"),
        (config(points=[*square()[:3], {"lat": 40, "lon": -181}]), "points[3].lon", "between"),
        (config(points=[*square()[:3], {"lat": 10**400, "lon": 0}]), "points[3].lat", "between"),
        (config(points=[*square()[:3], {"lat": math.inf, "lon": 0}]), "points[3].lat", "between"),
        (config(points=[*square()[:3], {"lat": 40, "lon": math.nan}]), "points[3].lon", "between"),
        (config(points=[*square()[:3], {"lat": 41.0, "lon": -8.66}]), "points[3]", "km"),
        (config(points=[*square(), square()[0]]), "points[4]", "zero-length"),
        (config(points=[square()[0], square()[0], *square()[1:]]), "points[1]", "zero-length"),
        (
            config(points=[point(-20, 20), point(20, -20), point(20, 20), point(-20, -20)]),
            "points",
            "cross",
        ),
        (
            config(points=[point(0, 0), point(20, 0), point(10, 0), point(10, 10)]),
            "points",
            "double back",
        ),
        (config(points=[point(0, 0), point(10, 0), point(20, 0)]), "points", "double back"),
        (
            config(points=[point(0, 0), point(20, 0), point(20, 20), point(10, 0), point(0, 20)]),
            "points",
            "touches",
        ),
        (config(grid_points=10), "grid_points", "multiple of 4"),
        (config(grid_points=16.0), "grid_points", "multiple of 4"),
        (config(grid_points=0), "grid_points", "multiple of 4"),
        (config(origin=point(0.0, 0.0)), "origin", "off the rail"),
        (config(origin=[0, 0]), "origin", "object"),
        (config(centre={"lat": 0, "lon": 0}), "points[0]", "km"),
        (config(name=""), "name", "non-empty"),
        (config(description=7), "description", "string"),
        (config(grid_point=16), "grid_point", "unknown field"),
    ],
)
def test_a_bad_config_is_refused_naming_the_field(body: Any, field: str, words: str) -> None:
    with pytest.raises(RailConfigError) as caught:
        Rail.from_mapping(body)
    assert caught.value.field == field
    assert words in caught.value.message
    assert str(caught.value).startswith(f"{field}: ")


def test_it_reads_json_and_toml_files(tmp_path: Path) -> None:
    json_path = tmp_path / "rail.json"
    json_path.write_text(json.dumps(config()), encoding="utf-8")
    lines = ['name = "toml rail"', "grid_points = 8"]
    for p in square():
        lines += ["[[points]]", f"lat = {p['lat']!r}", f"lon = {p['lon']!r}"]
    toml_path = tmp_path / "rail.toml"
    toml_path.write_text("\n".join(lines), encoding="utf-8")
    from_json, from_toml = Rail.from_file(json_path), Rail.from_file(toml_path)
    assert from_json.points == from_toml.points
    assert from_toml.name == "toml rail"
    assert from_toml.grid_points == 8


@pytest.mark.parametrize(
    ("name", "content", "field"),
    [
        ("rail.json", b"{not json", "json"),
        ("rail.json", b"\xff\xfe\x00", "json"),
        ("rail.json", b"[" * 100_000, "json"),
        ("rail.toml", b"points = [", "toml"),
        ("rail.toml", b"\xff", "file"),
        ("rail.json", b'{"points": []}', "points"),
    ],
)
def test_a_bad_file_is_refused_naming_the_problem(
    tmp_path: Path, name: str, content: bytes, field: str
) -> None:
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(RailConfigError) as caught:
        Rail.from_file(path)
    assert caught.value.field == field


def test_a_missing_file_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(RailConfigError, match="cannot read") as caught:
        Rail.from_file(tmp_path / "nowhere.json")
    assert caught.value.field == "file"


def test_points_given_in_code_obey_the_same_rules() -> None:
    with pytest.raises(RailConfigError, match=r"points\[1\]\.lat"):
        Rail([at(0, 0), (math.nan, 0.0), at(10, 10)])
    with pytest.raises(RailConfigError, match="grid_points"):
        Rail([at(0, 0), at(10, 0), at(10, 10)], grid_points=6)


json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=20),
    lambda children: (
        st.lists(children, max_size=6) | st.dictionaries(st.text(max_size=12), children, max_size=6)
    ),
    max_leaves=40,
)
coordinates = st.one_of(
    json_values,
    st.floats(min_value=40.633, max_value=40.6353),
    st.floats(min_value=-8.6615, max_value=-8.6585),
)
points_like = st.lists(
    st.fixed_dictionaries({"lat": coordinates, "lon": coordinates})
    | st.dictionaries(st.sampled_from(["lat", "lon", "x"]), coordinates, max_size=3),
    max_size=8,
)
configs_like = st.dictionaries(
    st.sampled_from(["name", "description", "centre", "points", "origin", "grid_points", "?"]),
    st.one_of(
        json_values, points_like, st.fixed_dictionaries({"lat": coordinates, "lon": coordinates})
    ),
    max_size=6,
)


@settings(max_examples=300)
@given(data=st.one_of(json_values, configs_like, st.fixed_dictionaries({"points": points_like})))
def test_any_json_value_is_a_rail_or_a_rail_config_error(data: Any) -> None:
    try:
        rail = Rail.from_mapping(data)
    except RailConfigError as exc:
        error: RailConfigError | None = exc
    else:
        error = None
        assert rail.length_m > 0
    assert error is None or (error.field and error.message)


@given(text=st.text(max_size=200) | st.binary(max_size=200))
def test_any_text_is_a_rail_or_a_rail_config_error(text: str | bytes) -> None:
    with pytest.raises(RailConfigError):
        Rail.from_json(text)
