"""Lamps in platform files (issue 35): ``[[lamps]]`` loads in SI units, bad entries are
refused naming the key, and ``sensors.shading.platform_lamps`` places them in the world
as SciPy's rotations do (fixed-axis roll, pitch, yaw; hypothesis over poses and lamp
attitudes); a platform lamp lights a floor by the inverse-square and cosine laws."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from raytrace import Scene
from sensors.camera import load_camera
from sensors.errors import PlatformError, SimulationError
from sensors.platform_spec import PLATFORM_DIR, PlatformLamp, load_platform
from sensors.render import camera_pose, render_depth
from sensors.shading import Lamp, luminance, platform_lamps

SPOT = """
[[lamps]]
kind = "spot"
xyz_m = [0.2, 0.1, 0.3]
rpy_deg = [0.0, 10.0, 20.0]
intensity_cd = 800.0
beam_deg = 15.0
cutoff_deg = 25.0
"""


def _tripod_with(tmp_path, extra):
    p = tmp_path / "lit.toml"
    p.write_text((PLATFORM_DIR / "tripod.toml").read_text() + extra)
    return p


def test_shipped_platforms_carry_their_lamps():
    robot, walker, trolley, tripod = (load_platform(n) for n in
                                      ("ground_robot", "walker", "trolley", "tripod"))
    assert [lp.kind for lp in robot.lamps] == ["spot", "spot"]
    # Two headlights, mirror images across the robot's centre plane, on its front face.
    a, b = robot.lamps
    assert a.xyz_m[0] == b.xyz_m[0] == pytest.approx(0.322 / 2)
    assert a.xyz_m[1] == -b.xyz_m[1] > 0
    # A walker's base_link is its platform frame, the handheld scanner (sensors.robot):
    # the helmet lamp is above it, at head height.
    assert len(walker.lamps) == 1 and \
        1.6 < walker.mast_height_m + walker.lamps[0].xyz_m[2] < 1.9
    assert len(trolley.lamps) == 2 and tripod.lamps == ()
    for lp in robot.lamps + walker.lamps + trolley.lamps:
        assert 0 < lp.beam_half_angle_rad <= lp.cutoff_half_angle_rad < math.pi / 2
        assert lp.intensity_cd > 0


def test_a_lamp_entry_loads_in_si_units(tmp_path):
    lp = load_platform(_tripod_with(tmp_path, SPOT)).lamps
    assert lp == (PlatformLamp("spot", (0.2, 0.1, 0.3),
                               (0.0, math.radians(10.0), math.radians(20.0)), 800.0,
                               math.radians(15.0), math.radians(25.0)),)
    pt = load_platform(_tripod_with(tmp_path, '[[lamps]]\nkind = "point"\n'
                                    'xyz_m = [0, 0, 2]\nintensity_cd = 50\n')).lamps
    assert pt == (PlatformLamp("point", (0.0, 0.0, 2.0), (0.0, 0.0, 0.0), 50.0),)


@pytest.mark.parametrize("old, new, match", [
    ("beam_deg", "beam_width", r"unknown key `beam_width` \(did you mean `beam_deg`\?\)"),
    ('kind = "spot"', 'kind = "flood"', r"`lamps\[0\].kind` .* one of \('spot', 'point'\)"),
    ("cutoff_deg = 25.0", "cutoff_deg = 10.0", "beam_deg` <= .*cutoff_deg` < 180"),
    ("cutoff_deg = 25.0", "cutoff_deg = 180.0", "beam_deg` <= .*cutoff_deg` < 180"),
    ("intensity_cd = 800.0", "intensity_cd = -1.0", r"`lamps\[0\].intensity_cd` .* >= 0"),
    ("xyz_m = [0.2, 0.1, 0.3]", "xyz_m = [0.2, 0.1]", r"`lamps\[0\].xyz_m` .* 3 finite"),
    ("cutoff_deg = 25.0\n", "", r"a key `cutoff_deg` in \[lamps\[0\]\]"),
    ('kind = "spot"', 'kind = "point"', "unknown keys `rpy_deg`, `beam_deg`, `cutoff_deg`"),
    ("[[lamps]]", "[[lamp]]", r"unknown key `lamp` \(did you mean `lamps`\?\)"),
    ("[[lamps]]", "[lamps]", "`lamps` .* an array of tables"),
])
def test_bad_lamp_entries_are_refused(tmp_path, old, new, match):
    assert old in SPOT
    with pytest.raises(PlatformError, match=match):
        load_platform(_tripod_with(tmp_path, SPOT.replace(old, new)))


def _rigid(rotvec, t):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


angles = st.floats(-math.pi, math.pi, allow_nan=False)
coords = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(rpy=st.tuples(angles, st.floats(-1.5, 1.5), angles),
       xyz=st.tuples(coords, coords, coords),
       rotvec=st.tuples(*[st.floats(-3.0, 3.0)] * 3),
       t=st.tuples(coords, coords, coords))
def test_platform_lamps_agree_with_scipy_rotations(rpy, xyz, rotvec, t):
    spec = load_platform("ground_robot")
    lamp = PlatformLamp("spot", xyz, rpy, 500.0, 0.2, 0.4)
    T = _rigid(rotvec, t)
    (got,) = platform_lamps(replace(spec, lamps=(lamp,)), T)
    R = Rotation.from_rotvec(rotvec)
    np.testing.assert_allclose(got.position, R.apply(xyz) + t, atol=1e-9)
    # URDF/SDF rpy: fixed axes x, y, z ("xyz" in SciPy's lower case = extrinsic).
    beam = R.apply(Rotation.from_euler("xyz", rpy).apply([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(got.direction, beam, atol=1e-12)
    assert (got.intensity_cd, got.beam_half_angle_rad, got.cutoff_half_angle_rad) == \
        (500.0, 0.2, 0.4)


def test_pose_errors_and_no_lamps():
    robot = load_platform("ground_robot")
    assert platform_lamps(load_platform("tripod"), np.eye(4)) == []
    with pytest.raises(SimulationError, match="finite 4x4"):
        platform_lamps(robot, np.eye(3))
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(SimulationError, match="rigid transform"):
        platform_lamps(robot, bad)


def test_a_headlight_lights_the_floor_by_inverse_square_and_cosine():
    """The robot's left headlight (tilted 5 deg down, 0.2 m up) over a floor: the
    luminance under the beam is rho I cos(theta) / (pi d^2) at every lit pixel of a
    camera looking down, with the spot's full intensity inside its beam."""
    robot = load_platform("ground_robot")
    T_base = _rigid([0.0, 0.0, math.radians(30.0)], [1.0, 2.0, 0.0])
    lamps = platform_lamps(robot, T_base)
    v = np.array([[-20, -20, 0], [20, -20, 0], [20, 20, 0], [-20, 20, 0.0]])
    scene = Scene(v, np.array([[0, 1, 2], [0, 2, 3]]))
    cam = replace(load_camera("realsense_d435_color"), width=80, height=60, fx=40.0,
                  fy=40.0, cx=39.5, cy=29.5, distortion=np.zeros(5))
    hit_ahead = lamps[0].position + lamps[0].direction * (0.2 / -lamps[0].direction[2])
    fr = render_depth(scene, cam, camera_pose(hit_ahead + [0, 0, 3.0], 0.0, -math.pi / 2))
    lum = luminance(scene, fr, lamps[:1], np.array([0.5]))[..., 0]
    p = fr.points[fr.hit]
    to = lamps[0].position - p
    d = np.linalg.norm(to, axis=1)
    cos_i = to[:, 2] / d
    off = np.degrees(np.arccos(np.clip(-(to / d[:, None]) @ lamps[0].direction, -1, 1)))
    inside = off < 20.0
    assert inside.sum() > 100
    np.testing.assert_allclose(lum[fr.hit][inside],
                               0.5 * 1000.0 * cos_i[inside] / (math.pi * d[inside] ** 2),
                               rtol=1e-12)
    assert np.all(lum[fr.hit][off > 35.0] == 0.0)
    # The beam's centre on the floor lies where the 5 deg tilt puts it: 0.2 / tan(5 deg)
    # ahead of the lamp, along the robot's heading (30 deg).
    ahead = np.linalg.norm(hit_ahead[:2] - lamps[0].position[:2])
    assert ahead == pytest.approx(0.2 / math.tan(math.radians(5.0)), rel=1e-12)
    assert math.degrees(math.atan2(*(hit_ahead - lamps[0].position)[1::-1])) == \
        pytest.approx(30.0)
    assert isinstance(lamps[0], Lamp)
