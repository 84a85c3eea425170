"""Robot case: board fit, sealed lid stack, fittings and frame slots where they belong."""

from __future__ import annotations

from dataclasses import replace

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cad import robot_case
from cad.geometry import exact_bounds, overlap_mm3
from tests.cad.probes import ALIGN_TOL_MM, fill_ratio, is_empty, ring, rod


def _size(shape):
    bb = exact_bounds(shape)
    return bb.xlen, bb.ylen, bb.zlen


def test_each_part_is_one_valid_solid(robot):
    assert set(robot.parts()) == {"base", "gasket", "lid"}
    for name, solid in robot.parts().items():
        assert solid.isValid(), name
        assert len(solid.Solids()) == 1, name


def test_board_does_not_touch_any_part(robot):
    board = robot.boards()["board"]
    for name, solid in robot.parts().items():
        assert overlap_mm3(board, solid) < 1e-3, name


def test_gasket_and_lid_stack_on_the_rim(robot):
    lay = robot.layout
    parts = robot.parts()
    for a, b in (("base", "gasket"), ("gasket", "lid"), ("base", "lid")):
        assert overlap_mm3(parts[a], parts[b]) < 1e-3, (a, b)
    assert exact_bounds(robot.gasket).zmin == pytest.approx(lay.rim)
    # Each rests on the one below: lowered a little, it runs into it.
    assert overlap_mm3(robot.gasket.translate((0, 0, -0.1)), robot.base) > 1.0
    assert overlap_mm3(robot.lid.translate((0, 0, -0.1)), robot.gasket) > 1.0
    # The skirt hangs outside the walls, below the gasket line.
    assert exact_bounds(robot.lid).zmin < lay.rim - 2.0
    lid_x, _lid_y, _ = _size(robot.lid)
    assert lid_x > lay.inner_l + 2 * robot.params.wall_mm


def test_board_holes_line_up_with_the_bosses(robot):
    p, lay = robot.params, robot.layout
    for hx, hy in p.board.holes_mm:
        x, y = lay.board_x0 + hx, lay.board_y0 + hy
        bore = rod((x, y, 1.0), p.pilot_d_mm - 2 * ALIGN_TOL_MM, lay.board_z - 1.0)
        assert is_empty(bore, robot.base), (hx, hy)
        wall = ring(
            (x, y, p.floor_mm + 2.0),
            p.pilot_d_mm + 2 * ALIGN_TOL_MM,
            p.boss_d_mm - 2 * ALIGN_TOL_MM,
            p.standoff_mm - 2.1,
        )
        assert fill_ratio(wall, robot.base) == pytest.approx(1.0, abs=1e-3)


def test_lid_screws_pass_lid_and_gasket_into_the_inserts(robot):
    p, lay = robot.params, robot.layout
    top = lay.lid_bottom + p.lid_mm
    bottom = lay.rim - p.lid_screw_depth_mm + 0.5
    for x, y in lay.shell.pillar_centres():
        bore = rod((x, y, bottom), p.lid_screw_d_mm - 2 * ALIGN_TOL_MM, top - bottom + 1)
        assert is_empty(bore, robot.base, robot.gasket, robot.lid), (x, y)
        insert_seat = ring(
            (x, y, bottom),
            p.insert_hole_d_mm + 2 * ALIGN_TOL_MM,
            p.pillar_d_mm - 2 * ALIGN_TOL_MM,
            p.lid_screw_depth_mm - 1.0,
        )
        assert fill_ratio(insert_seat, robot.base) == pytest.approx(1.0, abs=1e-3)
        # The gasket closes round every screw: water on a screw stays out of the cavity.
        seal = ring((x, y, lay.rim), p.lid_screw_d_mm + 0.4, p.pillar_d_mm - 0.4, p.gasket_mm)
        assert fill_ratio(seal, robot.gasket) == pytest.approx(1.0, abs=1e-3)


def test_glands_vent_and_bulkheads_go_through_the_end_walls(robot):
    p, lay = robot.params, robot.layout
    through = p.wall_mm + 2
    assert len(lay.fitting_ys) == len(p.glands) + 1
    for y in lay.fitting_ys:
        probe = rod((lay.inner_l - 1, y, lay.fitting_z), p.gland.hole_d_mm - 0.4, through, "X")
        assert is_empty(probe, robot.base), y
    assert len(lay.antenna_ys) == len(p.antennas)
    for y in lay.antenna_ys:
        probe = rod((-p.wall_mm - 1, y, lay.antenna_z), p.bulkhead.hole_d_mm - 0.4, through, "X")
        assert is_empty(probe, robot.base), y
        # The bulkhead's nut clears the lid's skirt.
        assert lay.antenna_z + p.bulkhead.nut_clearance_d_mm / 2 < lay.skirt_bottom
    # Nothing opens upwards: the floor and the lid are whole.
    assert robot.lid.isValid()
    solid_top = rod((lay.inner_l / 2, lay.inner_w / 2, lay.lid_bottom), 20.0, p.lid_mm - 0.5)
    assert fill_ratio(solid_top, robot.lid) == pytest.approx(1.0, abs=1e-3)


def test_frame_tabs_have_slots_along_the_rail(robot):
    p, lay = robot.params, robot.layout
    slots = lay.tab_slots(p)
    assert len(slots) == 4
    travel = (p.tab_slot_len_mm - p.tab_slot_w_mm) / 2
    for x, y in slots:
        for dx in (-travel, 0.0, travel):
            bolt = rod((x + dx, y, -1.0), p.tab_slot_w_mm - 0.4, p.tab_mm + 2)
            assert is_empty(bolt, robot.base), (x, y, dx)
        # Across the slot there is tab: the bolt is held sideways.
        beside = rod((x, y + p.tab_slot_w_mm / 2 + 1.5, 0.5), 2.0, p.tab_mm - 1.0)
        assert fill_ratio(beside, robot.base) == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize(
    ("change", "grow"),
    [
        ({"wall_mm": 4.0}, (2.0, 2.0, 0.0)),
        ({"standoff_mm": 11.0}, (0.0, 0.0, 3.0)),
        ({"gland_gap_mm": 20.0}, (5.0, 0.0, 0.0)),
        ({"tab_reach_mm": 20.0}, (0.0, 8.0, 0.0)),
    ],
)
def test_base_size_follows_the_parameters(robot, change, grow):
    changed = robot_case.build(replace(robot.params, **change))
    for b, a, g in zip(_size(robot.base), _size(changed.base), grow, strict=True):
        assert a - b == pytest.approx(g, abs=1e-6)


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"wall_mm": -1.0}, "wall_mm"),
        ({"wall_mm": 6.0}, "wall_mm"),
        ({"boss_d_mm": 8.0}, "boss_d_mm"),
        ({"antenna_gap_mm": 8.0}, "antenna_gap_mm"),
        ({"gland_gap_mm": 5.0}, "gland_gap_mm"),
        ({"fitting_pitch_mm": 12.0}, "fitting_pitch_mm"),
        ({"skirt_drop_mm": 40.0}, "skirt_drop_mm"),
        ({"tab_slot_len_mm": 4.0}, "tab_slot_len_mm"),
        ({"insert_hole_d_mm": 7.0}, "pillar_d_mm"),
        ({"lid_fillet_mm": 3.0}, "lid_fillet_mm"),
    ],
)
def test_bad_parameters_are_refused_by_name(change, named):
    with pytest.raises(ValueError, match=named):
        replace(robot_case.RobotCaseParams(), **change)


@settings(
    max_examples=4, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    wall=st.floats(min_value=2.0, max_value=4.5),
    clearance=st.floats(min_value=0.3, max_value=2.5),
    standoff=st.floats(min_value=4.0, max_value=12.0),
)
def test_any_sane_wall_clearance_and_standoff_fit_the_board(wall, clearance, standoff):
    params = replace(
        robot_case.RobotCaseParams(), wall_mm=wall, clearance_mm=clearance, standoff_mm=standoff
    )
    case = robot_case.build(params)
    for solid in case.parts().values():
        assert solid.isValid()
    board = case.boards()["board"]
    assert overlap_mm3(board, case.base) < 1e-3
    assert overlap_mm3(board, case.lid) < 1e-3
    x, _y, z = _size(case.base)
    assert x == pytest.approx(case.layout.inner_l + 2 * wall, abs=1e-6)
    assert z == pytest.approx(case.layout.rim, abs=1e-6)
