"""Files on disk: STEP round trip, STL, SVG, and the ``python -m cad`` command."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import cadquery as cq
import pytest

from cad.__main__ import main
from cad.export import write_step, write_stl, write_svg
from cad.geometry import exact_bounds

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def all_parts(bs, robot, gps, branch):
    parts = {}
    for model, built in (
        ("bs_case", bs),
        ("robot_case", robot),
        ("gps_mount", gps),
        ("antenna_branch", branch),
    ):
        for name, solid in built.parts().items():
            parts[f"{model}-{name}"] = solid
    return parts


def test_step_reimports_with_the_same_volume(all_parts, tmp_path):
    for name, solid in all_parts.items():
        path = write_step(solid, tmp_path / f"{name}.step")
        back = cq.importers.importStep(str(path)).val()
        assert isinstance(back, cq.Shape)
        assert back.isValid(), name
        assert back.Volume() == pytest.approx(solid.Volume(), rel=1e-3), name


def test_stl_is_a_closed_mesh_of_many_triangles(all_parts, tmp_path):
    solid = all_parts["robot_case-base"]
    path = write_stl(solid, tmp_path / "robot_case-base.stl")
    data = path.read_bytes()
    # Binary STL: 80-byte header, triangle count, 50 bytes per triangle.
    (count,) = struct.unpack_from("<I", data, 80)
    assert count > 1000
    assert len(data) == 84 + 50 * count
    bb = exact_bounds(solid)
    xs = [struct.unpack_from("<f", data, 84 + 50 * i + 12)[0] for i in range(count)]
    assert min(xs) == pytest.approx(bb.xmin, abs=0.05)
    assert max(xs) == pytest.approx(bb.xmax, abs=0.05)


def test_svg_drawing_is_written(gps, tmp_path):
    path = write_svg(gps.exploded(), tmp_path / "gps_mount.svg")
    text = path.read_text()
    assert text.count("<path") > 50
    assert "stroke-dasharray" in text  # the hidden-line group, left empty
    # Coordinates are rounded to keep the committed drawings small.
    assert "0.123456" not in text
    assert len(text) < 200_000


def test_build_writes_every_part_and_reports_it(tmp_path, capsys):
    svg_dir = tmp_path / "docs"
    assert (
        main(["build", "--out", str(tmp_path / "out"), "--svg-dir", str(svg_dir), "gps_mount"]) == 0
    )
    out = capsys.readouterr().out
    for part in ("bracket", "cradle"):
        for suffix in (".step", ".stl"):
            written = tmp_path / "out" / f"gps_mount-{part}{suffix}"
            assert written.stat().st_size > 1000
        assert f"gps_mount/{part}" in out
    assert " mm3 " in out
    assert " x " in out
    assert (svg_dir / "gps_mount.svg").read_text() == (
        tmp_path / "out" / "gps_mount.svg"
    ).read_text()


def test_unknown_model_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["build", "--out", str(tmp_path), "no_such_model"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "unknown model 'no_such_model'" in err
    assert "bs_case" in err
    assert not list(tmp_path.iterdir())


def test_unwritable_directory_is_one_line_and_exit_1(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    assert main(["build", "--out", str(blocker / "out"), "gps_mount"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "cannot write to" in err


def test_command_line_entry_point(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "cad", "build", "--out", str(tmp_path), "frobnicator"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "cad: error: unknown model 'frobnicator' (choose from bs_case, gps_mount, robot_case, "
        "antenna_branch)"
    ]
    bad_option = subprocess.run(
        [sys.executable, "-m", "cad", "build", "--colour", "red"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert bad_option.returncode == 2
    assert len(bad_option.stderr.strip().splitlines()) == 1
