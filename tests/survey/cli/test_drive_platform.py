"""Acceptance of platform drives (issues 20 and 22), on the files the user gets: the
ground truth ``<out>_true_trajectory.txt`` (TUM) of ``tunnelsim drive``.

Each drive uses a two-beam test sensor (2,000 pulses a second: the drives are about the
trajectory, not the cloud). The file is read back with ``Trajectory.read`` and
differentiated with ``sensors.bag.platform_motion`` (central differences, the IMU's
derivation) and with plain finite differences of its samples; clearances and heights
are brute force over every triangle (``tests.naive``).
"""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.shapes import tunnel_tube
from sensors import Trajectory
from sensors.imu import platform_motion
from sensors.platform_spec import load_platform
from survey.cli.main import main
from tests.naive import naive_cast, naive_point_mesh
from tests.sensors.test_route import bent_tube, plan_mesh

SENSOR = """
[device]
name = "test_two_beams"
vendor = "test"
model = "two beams"
kind = "spinning"
wavelength_nm = 905
sources = ["test sensor: 2 channels, 1 kHz columns"]
[range]
min_m = 0.1
max_m = 50.0
[detection]
range_m = 50.0
reflectivity = 0.8
softness = 0.1
[noise]
range_sigma_m = 0.0
reference_range_m = 10.0
reference_reflectivity = 0.5
range_sigma_floor_m = 0.0
angle_sigma_arcsec = 0.0
[beam]
divergence_half_mrad = 0.0
exit_diameter_mm = 0.0
[spinning]
rotation_hz = 10.0
column_period_us = 1000.0
elevations_deg = [-30.0, 10.0]
azimuth_offset_deg = 0.0
firing_group_size = 1
firing_group_step_us = 1.0
clockwise = true
"""
CLEAR = 0.2


def _write_mesh(path, v, f):
    import trimesh

    trimesh.Trimesh(v, f, process=False).export(path)
    return str(path)


@pytest.fixture()
def sensor(tmp_path):
    p = tmp_path / "two_beams.toml"
    p.write_text(SENSOR)
    return str(p)


def _drive(tmp_path, mesh, sensor, *extra):
    out = tmp_path / "d.npz"
    assert main(["drive", "--mesh", mesh, "--sensor", sensor, "--quiet", "-o", str(out),
                 *extra]) == 0
    return Trajectory.read(tmp_path / "d_true_trajectory.txt")


def _yaw(traj):
    m = traj.rotations.as_matrix()
    return np.unwrap(np.arctan2(m[:, 1, 0], m[:, 0, 0]))


def _check_limits(traj, name):
    """Yaw rate, yaw acceleration, horizontal acceleration and jerk at every sample
    within the platform's limits (0.1 % for the file's 1e-9 rounding)."""
    lim = load_platform(name).limits
    t = traj.times
    _, _, vel, omega, acc = platform_motion(traj, t)
    dt = np.diff(t)
    tol = 1.001
    assert np.linalg.norm(vel[:, :2], axis=1).max() <= lim.max_speed_mps * tol
    assert np.linalg.norm(acc[:, :2], axis=1).max() <= lim.max_accel_mps2 * tol
    jerk = np.diff(acc[:, :2], axis=0) / dt[:, None]
    assert np.linalg.norm(jerk, axis=1).max() <= lim.max_jerk_mps3 * tol
    yaw_rate = np.gradient(_yaw(traj), t)
    assert np.abs(yaw_rate).max() <= lim.max_yaw_rate_radps * tol
    assert np.abs(np.diff(yaw_rate) / dt).max() <= lim.max_yaw_accel_radps2 * tol
    assert np.abs(omega[:, 2]).max() <= lim.max_yaw_rate_radps * tol
    # from rest to rest
    assert np.linalg.norm(vel[[0, -1]], axis=1).max() < 1e-3
    return yaw_rate


def _check_height(traj, v, f, height_m, every=10):
    p = traj.positions[::every]
    assert naive_point_mesh(p, v, f)[0].min() >= CLEAR
    t = naive_cast(v, f, p, np.tile([0.0, 0, -1], (len(p), 1)))[0]
    np.testing.assert_allclose(t, height_m, atol=0.02)


def test_ground_robot_on_a_bend(tmp_path, sensor):
    v, f = bent_tube()                       # 16 m arc of radius 10 m
    mesh = _write_mesh(tmp_path / "bend.ply", v, f)
    traj = _drive(tmp_path, mesh, sensor, "--along", "auto", "--speed", "1")
    yaw_rate = _check_limits(traj, "ground_robot")
    assert np.abs(yaw_rate).max() == pytest.approx(0.1, rel=0.1)     # 1 m/s on r = 10 m
    _check_height(traj, v, f, 0.5)
    p = traj.positions
    ang = np.arctan2(p[:, 0], 10.0 - p[:, 1])
    assert np.ptp(ang) >= 0.9 * 1.6                                   # of the 1.6 rad arc
    lateral = np.hypot(p[:, 0], p[:, 1] - 10.0) - 10.0
    assert np.abs(lateral).max() <= 0.1


def test_ground_robot_round_a_corner_and_back(tmp_path, sensor):
    """A 90 degree turn, then back from a waypoint: the base stops and turns on the
    spot within its yaw limits."""
    plan = np.zeros((16, 16), bool)
    plan[:, :6] = True
    plan[:6, :] = True
    v, f = plan_mesh(plan, portals=("x+", "y+"))
    mesh = _write_mesh(tmp_path / "turn.ply", v, f)
    (tmp_path / "wp.csv").write_text("x,y\n7.5,1.5\n1.5,7.5\n1.5,3\n")
    traj = _drive(tmp_path, mesh, sensor, "--along", "auto", "--speed", "1",
                  "--waypoints", str(tmp_path / "wp.csv"))
    yaw_rate = _check_limits(traj, "ground_robot")
    assert np.ptp(_yaw(traj)) >= np.pi / 2 + np.pi - 0.2             # corner, turn back
    assert np.abs(yaw_rate).max() >= 0.5                             # a real turn
    _check_height(traj, v, f, 0.5)


def test_ground_robot_follows_a_ramp(tmp_path, sensor):
    """A tube rising at 8 % after 4 m: the mast stays 0.5 m above the floor (along the
    base's z), the base pitches with the floor and rolls not at all."""
    v, f = tunnel_tube(2400, length_m=12.0, roughness_m=0.0)
    v = v.copy()
    v[:, 2] += 0.08 * np.maximum(v[:, 0] - 4.0, 0.0)
    mesh = _write_mesh(tmp_path / "ramp.ply", v, f)
    traj = _drive(tmp_path, mesh, sensor, "--along", "auto", "--speed", "1")
    zb = traj.rotations.as_matrix()[:, :, 2]
    p = traj.positions
    # The limits are the base's, what its wheels drive: the mast's top lurches as the
    # base pitches over the kink at x = 4 (0.5 m x 0.08 rad within a wheelbase).
    _check_limits(Trajectory(traj.times, p - 0.5 * zb, traj.rotations), "ground_robot")
    on_ramp = (p[:, 0] > 5.0) & (p[:, 0] < 11.0)
    up = np.array([-0.08, 0.0, 1.0]) / np.hypot(1.0, 0.08)
    np.testing.assert_allclose(zb[on_ramp], np.tile(up, (on_ramp.sum(), 1)), atol=2e-3)
    base = p - 0.5 * zb                                              # on the floor
    floor = 0.08 * np.maximum(base[:, 0] - 4.0, 0.0)
    np.testing.assert_allclose(base[on_ramp, 2], floor[on_ramp], atol=0.02)


def test_walker_sways_at_its_gait_frequencies(tmp_path, sensor):
    """The walker's sensor bobs at the step frequency and sways sideways at half of it
    (once a stride): the FFT peaks of its height and lateral offset on the cruise."""
    v, f = tunnel_tube(3000, length_m=30.0, roughness_m=0.0)
    mesh = _write_mesh(tmp_path / "tube.ply", v, f)
    traj = _drive(tmp_path, mesh, sensor, "--along", "auto", "--speed", "1.2",
                  "--platform", "walker")
    gait = load_platform("walker").gait
    _, _, vel, _, _ = platform_motion(traj, traj.times)
    cruise = np.linalg.norm(vel[:, :2], axis=1) > 1.2 * 0.999
    t, p = traj.times[cruise], traj.positions[cruise]
    assert t[-1] - t[0] > 10.0
    rate = 1.0 / np.median(np.diff(traj.times))
    for sig, f_want in ((p[:, 2], gait.step_hz), (p[:, 1], gait.step_hz / 2)):
        x = sig - sig.mean()
        spec = np.abs(np.fft.rfft(x * np.hanning(len(x))))
        freq = np.fft.rfftfreq(len(x), 1.0 / rate)
        assert abs(freq[np.argmax(spec)] - f_want) <= 2 * freq[1]
    assert np.ptp(p[:, 2]) == pytest.approx(gait.bob_m, rel=0.05)
    q = traj.positions[::10]
    assert naive_point_mesh(q, v, f)[0].min() >= CLEAR
    t_down = naive_cast(v, f, q, np.tile([0.0, 0, -1], (len(q), 1)))[0]
    assert np.abs(t_down - 1.5).max() <= 0.5 * gait.bob_m + 1e-6      # 1.5 m, bobbing
    yaw = _yaw(traj)
    assert np.abs(np.gradient(yaw, traj.times)).max() <= \
        load_platform("walker").limits.max_yaw_rate_radps


def test_centreline_follows_the_grade_unless_level(tmp_path, sensor):
    """The generated tunnel's centreline drive (the trolley) pitches with its 1 % grade
    (issue 22); --level keeps today's level platform; positions are the same."""
    mesh = str(tmp_path / "bfo.ply")
    assert main(["tunnel", "-o", mesh, "--preset", "bfo", "--edge-length", "0.5",
                 "--relief", "none", "--quiet"]) == 0
    args = ["--along", "centreline", "--speed", "30", "--chainage", "20,60"]
    graded = _drive(tmp_path, mesh, sensor, *args)
    level = _drive(tmp_path, mesh, sensor, *args, "--level")
    np.testing.assert_array_equal(graded.positions, level.positions)
    d = np.diff(graded.positions, axis=0)
    grade = d[:, 2] / np.hypot(d[:, 0], d[:, 1])
    assert np.abs(grade).max() > 1e-3                                # the tunnel has one
    xb = graded.rotations.as_matrix()[:-1, :, 0]
    np.testing.assert_allclose(xb[:, 2] / np.hypot(xb[:, 0], xb[:, 1]), grade, atol=1e-6)
    assert np.abs(level.rotations.as_matrix()[:, 2, 0]).max() < 1e-12


@pytest.mark.parametrize("what, match", [
    ("key", "unknown key `wheel_base` (did you mean `wheelbase_m`?)"),
    ("plane", "encloses free space"),
    ("waypoint", "waypoint 2 (9, 4) inside the passage"),
    ("trajectory", "--platform with --along, got it with --trajectory"),
    ("speed", "at most the ground_robot's 1 m/s"),
    ("tripod", "--duration S"),
])
def test_bad_input_is_one_line_and_leaves_no_file(what, match, tmp_path, sensor, capsys,
                                                  monkeypatch):
    monkeypatch.chdir(tmp_path)
    tube = _write_mesh(tmp_path / "tube.ply", *tunnel_tube(1600, length_m=8.0,
                                                           roughness_m=0.0))
    with open(load_platform("ground_robot").path) as fh:
        text = fh.read()
    (tmp_path / "bad.toml").write_text(text.replace("wheelbase_m", "wheel_base"))
    (tmp_path / "wp.csv").write_text("x,y\n1,0\n9,4\n")
    plane = _write_mesh(tmp_path / "plane.ply", np.array(
        [[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0.0]]), np.array([[0, 1, 2], [1, 3, 2]]))
    Trajectory.along_polyline([[1.0, 0, 0.5], [7.0, 0, 0.5]], 1.0).write(tmp_path / "t.txt")
    extra = {"key": ["--along", "auto", "--speed", "1", "--platform", "bad.toml"],
             "plane": ["--along", "auto", "--speed", "1"],
             "waypoint": ["--along", "auto", "--speed", "1", "--waypoints", "wp.csv"],
             "trajectory": ["--trajectory", "t.txt", "--platform", "walker"],
             "speed": ["--along", "auto", "--speed", "2"],
             "tripod": ["--along", "auto", "--speed", "1", "--platform", "tripod"]}[what]
    before = set(tmp_path.iterdir())
    mesh = plane if what == "plane" else tube
    assert main(["drive", "--mesh", mesh, "--sensor", sensor, *extra, "-o", "x.npz"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and match in err, err
    assert set(tmp_path.iterdir()) == before
