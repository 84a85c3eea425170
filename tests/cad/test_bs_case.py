"""Base-station case: the boards fit, the screws find their holes, the air and plugs get in."""

from __future__ import annotations

from dataclasses import replace

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cad import bs_case
from cad.boards import RPI_4B
from cad.geometry import box, exact_bounds, overlap_mm3
from tests.cad.probes import ALIGN_TOL_MM, column, fill_ratio, is_empty, ring, rod


def _size(shape):
    bb = exact_bounds(shape)
    return bb.xlen, bb.ylen, bb.zlen


def test_each_part_is_one_valid_solid(bs):
    for name, solid in bs.parts().items():
        assert solid.isValid(), name
        assert len(solid.Solids()) == 1, name
        assert solid.Volume() > 1000, name


def test_boards_do_not_touch_the_case(bs):
    for name, board in bs.boards().items():
        assert overlap_mm3(board, bs.base) < 1e-3, name
        assert overlap_mm3(board, bs.lid) < 1e-3, name


def test_lid_sits_on_the_rim_without_interference(bs):
    assert overlap_mm3(bs.lid, bs.base) < 1e-3
    # Lowered by a tenth of a millimetre, the lid runs into the base: it rests on the rim.
    assert overlap_mm3(bs.lid.translate((0, 0, -0.1)), bs.base) > 1.0
    lid_x, lid_y, _ = _size(bs.lid)
    base_x, base_y, _ = _size(bs.base)
    assert lid_x == pytest.approx(base_x, abs=0.01)
    assert lid_y == pytest.approx(base_y - bs.params.shelf_depth_mm, abs=0.01)


def test_board_holes_line_up_with_the_bosses(bs):
    p, lay = bs.params, bs.layout
    for board, x0, y0, pilot in (
        (p.pi, lay.pi_x0, lay.pi_y0, p.pi_pilot_d_mm),
        (p.comm, lay.comm_x0, lay.comm_y0, p.comm_pilot_d_mm),
    ):
        for hx, hy in board.holes_mm:
            x, y = x0 + hx, y0 + hy
            # Open where the screw goes, from the floor skin to the board...
            bore = rod((x, y, 1.0), pilot - 2 * ALIGN_TOL_MM, lay.board_z - 1.0)
            assert is_empty(bore, bs.base), (board.name, hx, hy)
            # ...and solid all round it up to the board: the boss is centred on the hole.
            wall = ring(
                (x, y, p.floor_mm + 2.0),
                pilot + 2 * ALIGN_TOL_MM,
                p.boss_d_mm - 2 * ALIGN_TOL_MM,
                p.standoff_mm - 2.1,
            )
            assert fill_ratio(wall, bs.base) == pytest.approx(1.0, abs=1e-3)
            # The boss's top meets the board's underside.
            assert overlap_mm3(rod((x, y, lay.board_z), p.boss_d_mm, 0.2), bs.base) < 1e-3
            assert fill_ratio(
                ring((x, y, lay.board_z - 0.2), pilot + 0.5, p.boss_d_mm - 0.5, 0.2), bs.base
            ) == pytest.approx(1.0, abs=1e-3)


def test_lid_screw_holes_are_coaxial_with_the_pillars(bs):
    p, lay = bs.params, bs.layout
    depth = lay.shell.pillar_hole_depth_mm
    for x, y in lay.shell.pillar_centres():
        bore = rod(
            (x, y, lay.rim - depth + 0.5), p.lid_pilot_d_mm - 2 * ALIGN_TOL_MM, depth + p.lid_mm
        )
        assert is_empty(bore, bs.base, bs.lid), (x, y)
        grip = ring(
            (x, y, lay.rim - depth + 0.5),
            p.lid_pilot_d_mm + 2 * ALIGN_TOL_MM,
            p.pillar_d_mm - 2 * ALIGN_TOL_MM,
            depth - 1.0,
        )
        assert fill_ratio(grip, bs.base) == pytest.approx(1.0, abs=1e-3)


def _socket_probes(case):
    """For each Pi socket, a probe of its cross-section from its face out past the wall."""
    lay, pi = case.layout, case.params.pi
    out = 30.0
    probes = {}
    for port in pi.ports:
        t = ALIGN_TOL_MM
        z = lay.board_z + pi.thickness_mm + port.z_mm
        z0, z1 = z - port.height_mm / 2 + t, z + port.height_mm / 2 - t
        a0 = port.along_mm - port.width_mm / 2 + t
        a1 = port.along_mm + port.width_mm / 2 - t
        if port.edge == "x-":
            face = lay.pi_x0 - port.overhang_mm
            probes[port.name] = box(face - out, lay.pi_y0 + a0, z0, face, lay.pi_y0 + a1, z1)
        elif port.edge == "x+":
            face = lay.pi_x0 + pi.length_mm + port.overhang_mm
            probes[port.name] = box(face, lay.pi_y0 + a0, z0, face + out, lay.pi_y0 + a1, z1)
        elif port.edge == "y-":
            face = lay.pi_y0 - port.overhang_mm
            probes[port.name] = box(lay.pi_x0 + a0, face - out, z0, lay.pi_x0 + a1, face, z1)
        else:
            face = lay.pi_y0 + pi.width_mm + port.overhang_mm
            probes[port.name] = box(lay.pi_x0 + a0, face, z0, lay.pi_x0 + a1, face + out, z1)
    return probes


def test_every_pi_socket_faces_an_opening(bs):
    probes = _socket_probes(bs)
    assert set(probes) == {port.name for port in RPI_4B.ports}
    for name, probe in probes.items():
        assert is_empty(probe, bs.base, bs.lid), name


def test_without_sockets_the_walls_are_closed(bs):
    # The same probes hit the walls when the board declares no sockets (but the microSD card,
    # which the SD nozzle needs): the openings come from the sockets' positions.
    sd_only = tuple(port for port in RPI_4B.ports if port.name == "microsd")
    plain = bs_case.build(replace(bs.params, pi=replace(RPI_4B, ports=sd_only)))
    for name, probe in _socket_probes(bs).items():
        if name != "microsd":
            assert overlap_mm3(probe, plain.base) > 1.0, name


def test_duct_splits_the_fan_air_between_soc_and_sd_card(bs):
    p, lay = bs.params, bs.layout
    o = p.cpu_outlet_mm / 2 - 0.5
    # Straight down from the fan to the heat sink: open.
    down = column(
        lay.cpu_x - o,
        lay.cpu_y - o,
        lay.cpu_x + o,
        lay.cpu_y + o,
        lay.heatsink_top + 0.1,
        lay.rim - 0.1,
    )
    assert is_empty(down, bs.lid, bs.base)
    # Around that outlet the plenum has a floor, so the fan's pressure also feeds the channel.
    floor = ring(
        (lay.cpu_x, lay.cpu_y, lay.duct_bottom + 0.1),
        p.cpu_outlet_mm * 1.5,
        p.fan.size_mm - 4 * p.duct_wall_mm,
        p.duct_wall_mm - 0.2,
    )
    assert fill_ratio(floor, bs.lid) > 0.5
    # The nozzle's bore is open from the channel down to just above the microSD card...
    w, cw = p.duct_wall_mm, p.sd_channel_w_mm / 2
    bore = column(
        lay.nozzle_x0 + w + 0.1,
        lay.sd_y - cw + 0.1,
        lay.nozzle_x1 - w - 0.1,
        lay.sd_y + cw - 0.1,
        lay.nozzle_bottom - 0.5,
        lay.rim - 0.1,
    )
    assert is_empty(bore, bs.lid, bs.base)
    # ...and walled: the nozzle's sides are lid material.
    side = column(
        lay.nozzle_x0 + 0.1,
        lay.sd_y - cw,
        lay.nozzle_x0 + w - 0.1,
        lay.sd_y + cw,
        lay.nozzle_bottom + 0.1,
        lay.rim - p.sd_channel_h_mm,
    )
    assert fill_ratio(side, bs.lid) == pytest.approx(1.0, abs=1e-3)
    sd = RPI_4B.port("microsd")
    card_x0 = lay.pi_x0 - sd.overhang_mm
    assert lay.nozzle_x0 < card_x0 + 0.5 < lay.nozzle_x1
    # The channel joins the plenum: open from the nozzle to inside the fan's square.
    channel = column(
        lay.nozzle_x0 + w + 0.1,
        lay.sd_y - cw + 0.1,
        lay.cpu_x - p.fan.size_mm / 2 + w + 0.5,
        lay.sd_y + cw - 0.1,
        lay.rim - p.sd_channel_h_mm + 0.1,
        lay.rim - 0.1,
    )
    assert is_empty(channel, bs.lid)


def test_antenna_holders_take_sma_bulkheads(bs):
    p, lay = bs.params, bs.layout
    assert len(lay.antenna_xs) == len(p.antennas)
    for x in lay.antenna_xs:
        bore = rod(
            (x, lay.antenna_y, lay.rim - p.shelf_mm - 1), p.bulkhead.hole_d_mm - 0.2, p.shelf_mm + 2
        )
        assert is_empty(bore, bs.base)
        seat = ring(
            (x, lay.antenna_y, lay.rim - p.shelf_mm),
            p.bulkhead.hole_d_mm + 0.2,
            p.bulkhead.nut_af_mm,
            p.shelf_mm,
        )
        assert fill_ratio(seat, bs.base) == pytest.approx(1.0, abs=1e-3)
        pigtail = rod(
            (x, lay.inner_w - 1, lay.pigtail_z), p.pigtail_hole_d_mm - 0.2, p.wall_mm + 2, "Y"
        )
        assert is_empty(pigtail, bs.base)


@pytest.mark.parametrize(
    ("change", "grow"),
    [
        ({"wall_mm": 3.4}, (2.0, 2.0, 0.0)),
        ({"standoff_mm": 8.0}, (0.0, 0.0, 2.0)),
        ({"sd_gap_mm": 14.0}, (3.0, 0.0, 0.0)),
        ({"board_gap_mm": 9.0}, (0.0, 5.0, 0.0)),
    ],
)
def test_base_size_follows_the_parameters(bs, change, grow):
    changed = bs_case.build(replace(bs.params, **change))
    before, after = _size(bs.base), _size(changed.base)
    for b, a, g in zip(before, after, grow, strict=True):
        assert a - b == pytest.approx(g, abs=1e-6)


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"wall_mm": 0.0}, "wall_mm"),
        ({"clearance_mm": -0.5}, "clearance_mm"),
        ({"boss_d_mm": 6.5}, "boss_d_mm"),
        ({"boss_d_mm": 3.0}, "boss_d_mm"),
        ({"standoff_mm": 2.0}, "standoff_mm"),
        ({"sd_gap_mm": 3.0}, "sd_gap_mm"),
        ({"end_gap_mm": 4.0}, "end_gap_mm"),
        ({"side_gap_mm": 3.0}, "side_gap_mm"),
        ({"lid_screw_depth_mm": 60.0}, "lid_screw_depth_mm"),
        ({"corner_radius_mm": 12.0}, "corner_radius_mm"),
        ({"shelf_mm": 6.0}, "shelf_mm"),
        ({"grille_slot_mm": 8.0}, "grille_slot_mm"),
        ({"cpu_outlet_mm": 38.0}, "cpu_outlet_mm"),
        ({"antenna_pitch_mm": 10.0}, "antenna_pitch_mm"),
        ({"pi_pilot_d_mm": 3.0}, "pi_pilot_d_mm"),
    ],
)
def test_bad_parameters_are_refused_by_name(change, named):
    with pytest.raises(ValueError, match=named):
        replace(bs_case.BsCaseParams(), **change)


@settings(
    max_examples=4, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    wall=st.floats(min_value=1.6, max_value=3.2),
    clearance=st.floats(min_value=0.4, max_value=2.0),
)
def test_any_sane_wall_and_clearance_still_fit_the_boards(wall, clearance):
    params = replace(bs_case.BsCaseParams(), wall_mm=wall, clearance_mm=clearance)
    case = bs_case.build(params)
    for solid in case.parts().values():
        assert solid.isValid()
    for board in case.boards().values():
        assert overlap_mm3(board, case.base) < 1e-3
        assert overlap_mm3(board, case.lid) < 1e-3
    assert overlap_mm3(case.lid, case.base) < 1e-3
