"""GPS supports: coaxial axle holes, a detent at every step, no collision over the range."""

from __future__ import annotations

from dataclasses import replace

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from cad import antenna_branch, gps_mount
from cad.geometry import exact_bounds, overlap_mm3, polar
from cad.tilt import TiltJoint, cradle
from tests.cad.probes import ALIGN_TOL_MM, fill_ratio, is_empty, ring, rod


def _axle_probes(joint: TiltJoint, origin=(0.0, 0.0, 0.0)):
    """A rod through both ears along the axle, and the ears' material round it."""
    ox, oy, oz = origin
    span = 2 * joint.ear_outer_y_mm + 4
    start = (ox, oy - span / 2, oz)
    bore = rod(start, joint.axle_d_mm - 2 * ALIGN_TOL_MM, span, "Y")
    ears = [
        ring(
            (ox, oy + sign_y, oz),
            joint.axle_d_mm + 2 * ALIGN_TOL_MM,
            joint.axle_d_mm + 4,
            joint.ear_mm - 0.2,
            "Y",
        )
        for sign_y in (joint.ear_inner_y_mm + 0.1, -joint.ear_outer_y_mm + 0.1)
    ]
    return bore, ears


def _pin(joint: TiltJoint, tilt_deg: float, origin=(0.0, 0.0, 0.0)):
    x, z = polar(joint.detent_radius_mm, 90.0 - tilt_deg)
    span = 2 * joint.ear_outer_y_mm + 4
    return rod(
        (origin[0] + x, origin[1] - span / 2, origin[2] + z),
        joint.pin_d_mm - 2 * ALIGN_TOL_MM,
        span,
        "Y",
    )


def test_gps_mount_parts_are_valid_solids(gps):
    assert set(gps.parts()) == {"bracket", "cradle"}
    for name, solid in gps.parts().items():
        assert solid.isValid(), name
        assert len(solid.Solids()) == 1, name


def test_gps_mount_axle_holes_are_coaxial(gps):
    joint = gps.params.joint
    bore, ears = _axle_probes(joint)
    assert is_empty(bore, gps.bracket, gps.cradle)
    for ear in ears:
        assert fill_ratio(ear, gps.bracket) == pytest.approx(1.0, abs=1e-3)
    # The cradle's two lugs are bored on the same line and carry material round it.
    for sign in (-1, 1):
        y = sign * joint.lug_span_mm / 2 - (joint.lug_mm - 0.1 if sign > 0 else -0.1)
        lug = ring(
            (0, y, 0),
            joint.axle_d_mm + 2 * ALIGN_TOL_MM,
            joint.axle_d_mm + 4,
            joint.lug_mm - 0.2,
            "Y",
        )
        assert fill_ratio(lug, gps.cradle) == pytest.approx(1.0, abs=1e-3)


def test_gps_mount_has_a_detent_at_every_step_without_collision(gps):
    joint = gps.params.joint
    angles = joint.detent_angles_deg()
    assert angles == [-45.0, -30.0, -15.0, 0.0, 15.0, 30.0, 45.0]
    for angle in angles:
        tilted = gps.cradle_at(angle)
        assert overlap_mm3(tilted, gps.bracket) < 1e-3, angle
        # The detent bolt passes both ears and both lugs at this angle...
        assert is_empty(_pin(joint, angle), gps.bracket, tilted), angle
    # ...and between two marks it does not: the holes are discrete positions.
    between = gps.cradle_at(7.5)
    assert overlap_mm3(_pin(joint, 7.5), gps.bracket) > 1.0
    assert overlap_mm3(_pin(joint, 0.0), between) > 1.0


def test_gps_mount_size_follows_the_parameters(gps):
    bb = exact_bounds(gps.bracket)
    assert bb.xlen == pytest.approx(gps.params.base_l_mm)
    longer = gps_mount.build(replace(gps.params, base_l_mm=140.0))
    assert exact_bounds(longer.bracket).xlen == pytest.approx(140.0)
    taller_joint = replace(gps.params.joint, axle_height_mm=35.0)
    taller = gps_mount.build(replace(gps.params, joint=taller_joint))
    assert exact_bounds(taller.bracket).zlen - bb.zlen == pytest.approx(10.0)
    wider_platform = cradle(replace(gps.params.joint, platform_w_mm=130.0))
    assert exact_bounds(wider_platform).ylen == pytest.approx(130.0)


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"tilt_step_deg": 5.0}, "tilt_step_deg"),
        ({"tilt_max_deg": 85.0}, "tilt_max_deg"),
        ({"axle_height_mm": 8.0}, "axle_height_mm"),
        ({"axle_d_mm": 0.0}, "axle_d_mm"),
        ({"lug_span_mm": 12.0}, "lug_span_mm"),
        ({"antenna_hole_d_mm": 80.0}, "antenna_hole_d_mm"),
    ],
)
def test_bad_joint_parameters_are_refused_by_name(change, named):
    with pytest.raises(ValueError, match=named):
        replace(TiltJoint(), **change)


def test_bad_mount_parameters_are_refused_by_name():
    with pytest.raises(ValueError, match="base_l_mm"):
        gps_mount.GpsMountParams(base_l_mm=70.0)
    with pytest.raises(ValueError, match="slot_len_mm"):
        gps_mount.GpsMountParams(slot_len_mm=4.0)
    with pytest.raises(ValueError, match="base_mm"):
        gps_mount.GpsMountParams(base_mm=float("nan"))


def test_branch_parts_are_valid_solids(branch):
    assert set(branch.parts()) == {"branch", "cradle"}
    for name, solid in branch.parts().items():
        assert solid.isValid(), name
        assert len(solid.Solids()) == 1, name


def test_branch_holds_two_bulkheads_and_a_tilting_gps(branch):
    p = branch.params
    xs = p.antenna_xs_mm()
    assert len(xs) == 2
    for x in xs:
        bore = rod((x, 0, p.arm_top_mm - p.arm_mm - 1), p.bulkhead.hole_d_mm - 0.4, p.arm_mm + 2)
        assert is_empty(bore, branch.branch), x
        seat = ring(
            (x, 0, p.arm_top_mm - p.arm_mm),
            p.bulkhead.hole_d_mm + 0.4,
            p.bulkhead.nut_af_mm,
            p.arm_mm,
        )
        assert fill_ratio(seat, branch.branch) == pytest.approx(1.0, abs=1e-3)
    origin = (p.axle_x_mm, 0.0, p.axle_z_mm)
    bore, ears = _axle_probes(p.joint, origin)
    assert is_empty(bore, branch.branch, branch.cradle_at(0.0))
    for ear in ears:
        assert fill_ratio(ear, branch.branch) == pytest.approx(1.0, abs=1e-3)
    for angle in p.joint.detent_angles_deg():
        tilted = branch.cradle_at(angle)
        assert overlap_mm3(tilted, branch.branch) < 1e-3, angle
        assert is_empty(_pin(p.joint, angle, origin), branch.branch, tilted), angle


def test_branch_size_follows_the_parameters(branch):
    bb = exact_bounds(branch.branch)
    assert bb.xlen == pytest.approx(branch.params.arm_l_mm)
    longer = antenna_branch.build(replace(branch.params, arm_l_mm=230.0))
    assert exact_bounds(longer.branch).xlen == pytest.approx(230.0)
    taller = antenna_branch.build(replace(branch.params, stem_h_mm=90.0))
    assert exact_bounds(taller.branch).zlen - bb.zlen == pytest.approx(20.0)


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"arm_mm": 6.0}, "arm_mm"),
        ({"arm_w_mm": 20.0}, "arm_w_mm"),
        ({"antenna_pitch_mm": 8.0}, "antenna_pitch_mm"),
        ({"arm_l_mm": 120.0}, "arm_l_mm"),
        ({"stem_slot_len_mm": 60.0}, "stem_slot_len_mm"),
    ],
)
def test_bad_branch_parameters_are_refused_by_name(change, named):
    with pytest.raises(ValueError, match=named):
        replace(antenna_branch.AntennaBranchParams(), **change)


@settings(
    max_examples=6, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    tilt_max=st.sampled_from([15.0, 30.0, 45.0, 60.0]),
    step=st.sampled_from([15.0, 20.0, 30.0]),
    radius=st.floats(min_value=24.0, max_value=34.0),
)
def test_any_valid_joint_clears_the_fork_at_its_extremes(tilt_max, step, radius):
    assume(step <= tilt_max)
    joint = replace(
        gps_mount.GpsMountParams().joint,
        tilt_max_deg=tilt_max,
        tilt_step_deg=step,
        detent_radius_mm=radius,
        axle_height_mm=40.0,
    )
    mount = gps_mount.build(gps_mount.GpsMountParams(joint=joint, base_l_mm=160.0))
    assert mount.bracket.isValid()
    for angle in (joint.detent_angles_deg()[0], joint.detent_angles_deg()[-1]):
        tilted = mount.cradle_at(angle)
        assert overlap_mm3(tilted, mount.bracket) < 1e-3
        assert is_empty(_pin(joint, angle), mount.bracket, tilted)
