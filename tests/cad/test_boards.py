"""Board data: the published Pi 4 numbers, and malformed boards refused."""

from __future__ import annotations

from dataclasses import replace

import pytest

from cad.boards import BS_COMM_BOARD, ROBOT_BOARD, RPI_4B, Component, Port, board_solid
from cad.geometry import exact_bounds


def test_pi4_mounting_holes_follow_the_drawing():
    xs = sorted({x for x, _ in RPI_4B.holes_mm})
    ys = sorted({y for _, y in RPI_4B.holes_mm})
    assert (RPI_4B.length_mm, RPI_4B.width_mm) == (85.0, 56.0)
    assert xs == [3.5, 61.5]
    assert ys == [3.5, 52.5]
    assert RPI_4B.hole_d_mm == pytest.approx(2.7)


def test_pi4_sockets_sit_where_the_drawing_puts_them():
    along = {p.name: (p.edge, p.along_mm) for p in RPI_4B.ports}
    assert along["usb-c power"] == ("y-", 11.2)
    assert along["micro-hdmi 0"] == ("y-", 26.0)
    assert along["micro-hdmi 1"] == ("y-", 39.5)
    assert along["audio"] == ("y-", 54.0)
    assert along["usb 2.0"] == ("x+", 9.0)
    assert along["usb 3.0"] == ("x+", 27.0)
    assert along["ethernet"] == ("x+", 45.75)


@pytest.mark.parametrize("board", [RPI_4B, BS_COMM_BOARD, ROBOT_BOARD], ids=lambda b: b.name)
def test_board_solid_is_valid_and_as_tall_as_its_tallest_part(board):
    solid = board_solid(board)
    assert solid.isValid()
    bb = exact_bounds(solid)
    assert bb.zmax == pytest.approx(board.top_mm)
    assert bb.zmin == pytest.approx(-board.underside_mm)


def test_malformed_boards_are_refused():
    with pytest.raises(ValueError, match="off the board"):
        replace(RPI_4B, holes_mm=((1.0, 1.0),))
    with pytest.raises(ValueError, match="pad_d_mm"):
        replace(RPI_4B, pad_d_mm=2.0)
    with pytest.raises(ValueError, match="covers hole"):
        replace(ROBOT_BOARD, components=(Component("big", 10.0, 10.0, 15.0, 15.0, 5.0),))
    with pytest.raises(ValueError, match="does not sit on the board"):
        replace(ROBOT_BOARD, components=(Component("wide", 50.0, 35.0, 120.0, 10.0, 5.0),))
    with pytest.raises(ValueError, match="overhang_mm"):
        Port("usb", "x+", 9.0, 13.5, 16.0, 8.0, 17.5, 20.0, 15.0, 17.0)
    with pytest.raises(ValueError, match="opening"):
        Port("usb", "x+", 9.0, 13.5, 16.0, 8.0, 17.5, 2.5, 10.0, 17.0)
