"""Platforms as data and their motion (``sensors.platform``): every shipped file loads
with a unique name, bad files are refused naming the key; a wheeled or walking platform
driven along any smooth path stays within its limits at every sample (hypothesis),
starts and ends at rest and stays on the path; its attitude follows a tilted floor
(analytic plane); a rail platform is ``Trajectory.along_polyline``; a tripod is static.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from raytrace import Scene
from sensors import Trajectory
from sensors.errors import PlatformError
from sensors.platform import RIDE_SIGMA_S, platform_trajectory
from sensors.platform_spec import PLATFORM_DIR, list_platforms, load_platform
from tests.sensors.test_route import plan_mesh


def test_every_shipped_platform_loads_with_a_unique_name():
    files = sorted(PLATFORM_DIR.glob("*.toml"))
    names = [load_platform(f).name for f in files]
    assert len(set(names)) == len(files) == len(list_platforms()) >= 4
    assert {"ground_robot", "trolley", "walker", "tripod"} <= set(names)
    robot = load_platform("ground_robot")
    assert (robot.wheelbase_m, robot.track_m, robot.limits.max_speed_mps) == (0.2, 0.175, 1.0)
    assert repr(robot) == "PlatformSpec(ground_robot: wheeled, mast 0.5 m, up to 1 m/s, " \
                          "60 deg/s)"


@pytest.mark.parametrize("edit, match", [
    (("wheelbase_m", "wheel_base"), r"unknown key `wheel_base` \(did you mean `wheelbase_m`\?\)"),
    (("[limits]", "[limit]"), "unknown key `limit`"),
    (("max_jerk_mps3 = 1.0", "max_jerk_mps3 = -1.0"), "`limits.max_jerk_mps3` .* > 0"),
    (("track_m = 0.175", ""), "a key `track_m` in \\[body\\]"),
    (('motion = "wheeled"', 'motion = "flying"'), "`platform.motion` .* one of"),
    (("[body]", "[gait]\nstep_hz = 2\n[body]"), "unknown key `gait`"),
    (("[platform]", "[platform"), "valid TOML"),
])
def test_bad_platform_files_are_refused(edit, match, tmp_path):
    text = (PLATFORM_DIR / "ground_robot.toml").read_text()
    assert edit[0] in text
    p = tmp_path / "bad.toml"
    p.write_text(text.replace(edit[0], edit[1]))
    with pytest.raises(PlatformError, match=match):
        load_platform(p)


def test_unknown_names_and_files():
    with pytest.raises(PlatformError, match="platform name in"):
        load_platform("hovercraft")
    with pytest.raises(PlatformError, match="does not exist"):
        load_platform("no/such.toml")


def _motion(traj):
    """Speed, acceleration, jerk (horizontal), yaw rate and yaw acceleration at every
    sample, by finite differences of the poses (independent of the module's)."""
    t, p = traj.times, traj.positions[:, :2]
    m = traj.rotations.as_matrix()
    yaw = np.unwrap(np.arctan2(m[:, 1, 0], m[:, 0, 0]))
    v = np.gradient(p, t, axis=0)
    a = np.gradient(v, t, axis=0)
    j = np.diff(a, axis=0) / np.diff(t)[:, None]
    w = np.gradient(yaw, t)
    al = np.diff(w) / np.diff(t)
    n = np.linalg.norm
    return n(v, axis=1), n(a, axis=1), n(j, axis=1), np.abs(w), np.abs(al)


def _within(traj, lim, tol=1.001):
    v, a, j, w, al = _motion(traj)
    assert v.max() <= lim.max_speed_mps * tol
    assert a.max() <= lim.max_accel_mps2 * tol
    assert j.max() <= lim.max_jerk_mps3 * tol
    assert w.max() <= lim.max_yaw_rate_radps * tol
    assert al.max() <= lim.max_yaw_accel_radps2 * tol
    assert v[0] < 1e-3 and v[-1] < 1e-3


def _gap(a, b):
    """Largest distance from a point of a (n, 2) to the polyline b (m, 2)."""
    t = np.linspace(0, 1, 11)[:, None, None]
    dense = (b[:-1] + t * (b[1:] - b[:-1])).reshape(-1, 2)
    return max(np.min(np.linalg.norm(dense - p, axis=1)) for p in a)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(turns=st.lists(st.floats(-0.5, 0.5), min_size=2, max_size=5),
       speed=st.floats(0.3, 1.0), name=st.sampled_from(["ground_robot", "walker"]))
def test_any_smooth_path_stays_within_the_limits(turns, speed, name):
    """A path of 4 m legs turning by up to 0.5 rad at each vertex, smoothed as the
    route finder's are (Gaussian, 0.5 m): every sample within the limits, from rest to
    rest, on the path to 5 cm (the walker's sway aside)."""
    heading = np.cumsum([0.0, *turns])
    corners = np.vstack([[0.0, 0.0], np.cumsum(4.0 * np.column_stack(
        [np.cos(heading), np.sin(heading)]), axis=0)])
    seg = np.linalg.norm(np.diff(corners, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    ss = np.arange(0.0, s[-1], 0.25)
    from scipy.ndimage import gaussian_filter1d
    xy = np.column_stack([np.interp(ss, s, corners[:, k]) for k in range(2)])
    xy = gaussian_filter1d(xy, 2.0, axis=0, mode="nearest")
    path = np.column_stack([xy, np.full(len(xy), 0.5)])
    spec = load_platform(name)
    traj = platform_trajectory(path, spec, speed)
    if name == "ground_robot":
        _within(traj, spec.limits)
        assert _gap(traj.positions[::20, :2], xy) <= 0.05
        np.testing.assert_allclose(traj.positions[:, 2], 0.5 - 0.5 + spec.mast_height_m)
    else:                               # the yaw is the path's; the sway is on top
        _, _, _, w, al = _motion(traj)
        assert w.max() <= spec.limits.max_yaw_rate_radps * 1.001
        assert _gap(traj.positions[::20, :2], xy) <= 0.05 + spec.gait.sway_m / 2
    np.testing.assert_allclose(traj.positions[[0, -1], :2], xy[[0, -1]], atol=1e-6)


def test_a_tilted_floor_tilts_the_base():
    """A passage whose floor is the plane z = 0.05 x + 0.1 y: the base's z axis is the
    plane's normal, the mast top 0.5 m along it above the plane."""
    plan = np.zeros((30, 6), bool)
    plan[:] = True
    v, f = plan_mesh(plan, portals=("x-", "x+"))
    v = v.copy()
    v[:, 2] += 0.05 * v[:, 0] + 0.1 * v[:, 1]
    scene = Scene(v, f)
    x = np.linspace(2.0, 13.0, 23)
    path = np.column_stack([x, np.full_like(x, 1.5), 0.05 * x + 0.15 + 0.5])
    spec = load_platform("ground_robot")
    traj = platform_trajectory(path, spec, 1.0, scene=scene)
    n = np.array([-0.05, -0.1, 1.0]) / np.linalg.norm([-0.05, -0.1, 1.0])
    zb = traj.rotations.as_matrix()[:, :, 2]
    np.testing.assert_allclose(zb, np.tile(n, (len(zb), 1)), atol=1e-6)
    base = traj.positions - 0.5 * zb
    # The ride smooths the floor in time (Gaussian, sigma RIDE_SIGMA_S): while the base
    # speeds up at a, a floor rising at grade g along the path is lifted by the
    # smoothing of g a t^2 / 2, i.e. g a sigma^2 / 2 (0.9 mm here); 0.1 mm besides.
    g, sig = 0.05, RIDE_SIGMA_S
    tol = 0.5 * g * spec.limits.max_accel_mps2 * sig ** 2 + 1e-4
    np.testing.assert_allclose(base[:, 2], 0.05 * base[:, 0] + 0.1 * base[:, 1], atol=tol)
    level = platform_trajectory(path, spec, 1.0, scene=scene, follow_grade=False)
    np.testing.assert_allclose(level.rotations.as_matrix()[:, 2, 2], 1.0)


def test_rail_is_along_polyline_and_tripod_is_static():
    path = np.array([[0.0, 0, 0.5], [5.0, 0, 0.55], [9.0, 3.0, 0.6]])
    rail = platform_trajectory(path, "trolley", 3.0, accel_mps2=1.0)
    ref = Trajectory.along_polyline(path, 3.0, accel_mps2=1.0, follow_grade=True)
    np.testing.assert_array_equal(rail.positions, ref.positions)
    np.testing.assert_array_equal(rail.rotations.as_quat(), ref.rotations.as_quat())
    tripod = platform_trajectory(path, "tripod", 1.0, start_time=2.0)
    assert len(tripod) == 1 and tripod.start_s == 2.0
    np.testing.assert_array_equal(tripod.positions[0], path[0])


def test_turning_back_stops_and_turns_on_the_spot():
    path = np.array([[0.0, 0, 0.5], [3.0, 0, 0.5], [6.0, 0, 0.5], [3.0, 0.0, 0.5],
                     [0.0, 0.0, 0.5]])
    spec = load_platform("ground_robot")
    traj = platform_trajectory(path, spec, 1.0)
    _within(traj, spec.limits)
    m = traj.rotations.as_matrix()
    yaw = np.unwrap(np.arctan2(m[:, 1, 0], m[:, 0, 0]))
    assert abs(abs(yaw[-1] - yaw[0]) - np.pi) < 1e-9
    assert traj.positions[:, 0].max() == pytest.approx(6.0, abs=1e-6)


def test_limits_are_refused_when_asked_beyond():
    path = [[0.0, 0, 0.5], [5.0, 0, 0.5]]
    with pytest.raises(PlatformError, match="at most the ground_robot's 1 m/s"):
        platform_trajectory(path, "ground_robot", 1.5)
    with pytest.raises(PlatformError, match="acceleration at most"):
        platform_trajectory(path, "ground_robot", 1.0, accel_mps2=2.0)
    with pytest.raises(PlatformError, match="at least 2 points"):
        platform_trajectory([[0.0, 0, 0]], "ground_robot", 1.0)
