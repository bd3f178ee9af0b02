"""Real LiDAR odometry in the loop (issue 15): the pose stamps of KISS-ICP and GenZ-ICP,
platform poses through a mount, drives read back and re-placed, and `tunnelsim slam`
on its artefacts (the trajectory, the evaluation against evo's definitions, the
re-placed cloud, the control points) and on bad input."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from raytrace import Scene
from raytrace.shapes import icosphere
from sensors import Mount, Settings, Trajectory, load_sensor, simulate_drive
from survey.adjust.odometry import (
    MIN_FRAMES,
    STAMP,
    OdometryResult,
    odometry_trajectory,
    run_odometry,
)
from survey.adjust.slam import slam_trajectory, to_slam_frame
from survey.analysis.trajectory import trajectory_errors
from survey.cli.main import main
from survey.clouds.drives import frames_from_points, iter_frames, open_drive, replace_drive
from survey.errors import OdometryError
from sensors.io.errors import PointFileError

pytest.importorskip("kiss_icp")
pytest.importorskip("genz_icp")


# ------------------------------------------------------------------ pose stamps
@pytest.fixture(scope="module")
def room_drive():
    """An ideal Airy in a feature-rich room (a sphere of 25 m with 100 balls): still
    for 1 s, then 2 m/s and a gentle turn. Rich geometry: odometry tracks to ~1 cm, so
    a wrong pose stamp (5-10 cm of motion per half frame) stands out."""
    rng = np.random.default_rng(0)
    sv, sf = icosphere(2, 1.0)
    verts, faces, n = [sv * 25.0], [sf[:, ::-1]], len(sv)
    for _ in range(100):
        c = rng.uniform([-20, -20, -5], [20, 20, 8])
        if np.linalg.norm(c[:2]) < 4:
            continue
        verts.append(sv * rng.uniform(0.3, 1.5) + c)
        faces.append(sf + n)
        n += len(sv)
    scene = Scene(np.vstack(verts), np.vstack(faces))
    traj = Trajectory([0.0, 1.0, 3.0], [[0, 0, 0], [0, 0, 0], [4.0, 0.5, 0]],
                      Rotation.from_euler("z", [[0.0], [0.0], [0.2]]))
    run = simulate_drive(scene, load_sensor("robosense_airy"), traj, Mount(),
                         settings=Settings.ideal(), seed=1)
    return np.concatenate(list(run)), traj


def _along_error(res: OdometryResult, traj: Trajectory, shift_s: float = 0.0) -> float:
    """Mean error along the motion of the estimated sensor positions (anchored at the
    true first pose) over the moving frames, with the stamps moved by ``shift_s``: a
    stamp off by dt shows as v dt along the motion, whatever else the odometry gets
    wrong."""
    t = np.clip(res.times + shift_s, traj.start_s, traj.end_s)
    p, r = traj.sensor_matrices(t, Mount())
    first = np.eye(4)
    first[:3, :3], first[:3, 3] = r[0], p[0]
    est = np.einsum("ij,njk->nik", first, res.poses)
    ahead, _ = traj.sensor_matrices(np.minimum(t + 0.01, traj.end_s), Mount())
    v = ahead - p
    moving = (res.times > 1.3) & (np.linalg.norm(v, axis=1) > 1e-3)
    u = v[moving] / np.linalg.norm(v[moving], axis=1)[:, None]
    return float(np.mean(np.sum((est[moving, :3, 3] - p[moving]) * u, axis=1)))


@pytest.mark.parametrize("method", ["kiss-icp", "genz-icp"])
def test_pose_stamps_are_the_backends_own(room_drive, method):
    """KISS-ICP's pose is the frame's last instant, GenZ-ICP's its middle (module
    doc): with those stamps the mean error along the motion is within 3 cm; half a
    frame earlier or later (0.05 s = 10 cm at 2 m/s) is off by more than 6 cm."""
    pts, traj = room_drive
    res = run_odometry(frames_from_points([pts]), method=method)
    period = float(np.median(np.diff(res.times)))
    assert abs(_along_error(res, traj)) < 0.03, method
    for shift in (-0.5 * period, 0.5 * period):
        assert abs(_along_error(res, traj, shift)) > 0.06, (method, shift)
    assert STAMP[method] in (0.5, 1.0)


# ------------------------------------------------------------------ mount algebra
@settings(max_examples=25, deadline=None)
@given(lever=st.tuples(*[st.floats(-1, 1)] * 3),
       rpy=st.tuples(*[st.floats(-np.pi, np.pi)] * 3), seed=st.integers(0, 2 ** 16))
def test_platform_poses_through_any_mount_recover_the_truth(lever, rpy, seed):
    """Sensor poses made from a true platform trajectory through a mount, expressed
    relative to the first frame as odometry gives them, come back as the platform
    trajectory (anchored at the true start) to rounding, for any mount."""
    rng = np.random.default_rng(seed)
    n = 30
    t = np.arange(n) * 0.1
    truth = Trajectory(t, np.cumsum(rng.normal(0, 0.1, (n, 3)), axis=0) + [5e5, 5.2e6, 300],
                       Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0)))
    mount = Mount(lever, Rotation.from_euler("xyz", rpy))
    pos, mat = truth.sensor_matrices(t, mount)
    s = np.tile(np.eye(4), (n, 1, 1))
    s[:, :3, :3], s[:, :3, 3] = mat, pos - truth.origin
    rel = np.einsum("ij,njk->nik", np.linalg.inv(s[0]), s)
    res = OdometryResult("kiss-icp", t, rel, np.arange(n))
    start = truth.interpolate([t[0]])
    est = odometry_trajectory(res, mount, start=(start[0][0], start[1][0]))
    np.testing.assert_allclose(est.positions, truth.positions, atol=1e-6)
    d = (est.rotations * truth.rotations.inv()).magnitude()
    assert d.max() < 1e-9


def test_platform_trajectory_extends_with_constant_velocity():
    t = np.array([1.0, 1.1, 1.2])
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [0.0, 0.2, 0.4]
    est = odometry_trajectory(OdometryResult("kiss-icp", t, poses, np.arange(3)),
                              span_s=(0.9, 1.35))
    assert est.times[0] == 0.9 and est.times[-1] == 1.35
    np.testing.assert_allclose(est.positions[:, 0], [-0.2, 0, 0.2, 0.4, 0.7], atol=1e-12)


def test_too_few_frames_and_bad_settings_are_refused(room_drive):
    pts, _ = room_drive
    few = pts[pts["frame"] < MIN_FRAMES - 2]
    with pytest.raises(OdometryError, match="at least 10 whole scan frames"):
        run_odometry(frames_from_points([few]))
    with pytest.raises(OdometryError, match="odometry in"):
        run_odometry(frames_from_points([few]), method="loam")
    with pytest.raises(OdometryError, match="voxel_size_m"):
        run_odometry(frames_from_points([few]), voxel_size_m=0)


# ------------------------------------------------------------------ drive files
@pytest.fixture(scope="module")
def drive_dir(tmp_path_factory):
    """A short Airy drive through a rough gallery, 1 s still at each end, full fields,
    and the profiler on the same platform."""
    d = tmp_path_factory.mktemp("slam")
    assert main(["tunnel", "--preset", "bfo", "--edge-length", "0.25", "--roughness-mm",
                 "100", "-o", str(d / "t.ply"), "--quiet"]) == 0
    common = ["--mesh", str(d / "t.ply"), "--along", "centreline", "--speed", "3",
              "--chainage", "5,14", "--standstill", "1", "--fields", "full", "--quiet"]
    assert main(["drive", *common, "-o", str(d / "airy.laz")]) == 0
    assert main(["drive", *common, "--sensor", "zf_profiler_9012", "--rate", "25",
                 "--lever", "0.3,0,0.2", "-o", str(d / "prof.laz")]) == 0
    return d


@pytest.mark.slow
def test_drive_records_mount_and_truth(drive_dir):
    prof = open_drive(drive_dir / "prof.laz")
    assert prof.mount_recorded and prof.mount.lever_arm_m == (0.3, 0.0, 0.2)
    truth = Trajectory.read(drive_dir / "prof_true_trajectory.txt")
    # Still 1 s at each end: the first and last second share their pose.
    assert truth.duration_s == pytest.approx(3.0 + 2.0, abs=1e-3)   # 1 % grade: 9.0005 m
    p = truth.interpolate([0.0, 0.99, truth.end_s - 0.99, truth.end_s])[0]
    assert np.allclose(p[0], p[1]) and np.allclose(p[2], p[3])
    frames = list(iter_frames(open_drive(drive_dir / "airy.laz")))
    assert [f.frame for f in frames] == sorted({f.frame for f in frames})
    assert sum(len(f.times) for f in frames) == open_drive(drive_dir / "airy.laz").n_points


def test_replace_with_the_truth_gives_the_points_back(drive_dir, tmp_path):
    """Re-placing the sensor-frame points with the true trajectory (through the
    recorded mount) reproduces the world coordinates (to the LAS scale); with a
    drifted trajectory it equals ``to_slam_frame`` of the true points, a formula
    that uses only world points and the two trajectories."""
    drive = open_drive(drive_dir / "prof.laz")
    truth = Trajectory.read(drive_dir / "prof_true_trajectory.txt")
    orig = laspy.read(drive_dir / "prof.laz")
    xyz = np.stack([orig.x, orig.y, orig.z], 1)
    assert replace_drive(drive, tmp_path / "same.laz", truth) == len(xyz)
    same = laspy.read(tmp_path / "same.laz")
    assert np.abs(np.stack([same.x, same.y, same.z], 1) - xyz).max() < 2e-4
    drifted = slam_trajectory(truth, heading_rw=2e-3, pitch_rw=1e-3, seed=4)
    replace_drive(drive, tmp_path / "moved.laz", drifted)
    moved = laspy.read(tmp_path / "moved.laz")
    want = to_slam_frame(truth, drifted, xyz, np.asarray(orig.gps_time))
    got = np.stack([moved.x, moved.y, moved.z], 1)
    assert np.abs(got - want).max() < 2e-4
    assert np.abs(got - xyz).max() > 0.01          # the drift did move the points
    with pytest.raises(PointFileError, match="spanning the drive"):
        replace_drive(drive, tmp_path / "x.laz", Trajectory(truth.times[:50],
                                                            truth.positions[:50],
                                                            truth.rotations[:50]))


@pytest.fixture(scope="module")
def slam_run(drive_dir):
    d = drive_dir
    assert main(["slam", str(d / "airy.laz"), "-o", str(d / "est.txt"), "--truth",
                 str(d / "airy_true_trajectory.txt"), "--cloud", str(d / "mls.laz"),
                 "--place", str(d / "prof.laz"), "--control", str(d / "t.json"),
                 "--quiet"]) == 0
    return d


def test_slam_writes_a_trajectory_that_tracks(slam_run):
    d = slam_run
    est = Trajectory.read(d / "est.txt")
    truth = Trajectory.read(d / "airy_true_trajectory.txt")
    # The whole drive is covered (extrapolated past the partial first/last frames).
    drive = open_drive(d / "airy.laz")
    assert est.start_s <= drive.time_span_s[0] and est.end_s >= drive.time_span_s[1]
    # It tracks: the platform moved 9 m; the estimate ends within 20 cm of the truth.
    err = trajectory_errors(est, truth)
    assert err.path_length_m == pytest.approx(9.0, abs=0.05)
    assert err.final_error_m < 0.2


def test_slam_json_and_report_are_the_evaluation_of_the_files(slam_run):
    """The figures written are those of the trajectory written, evaluated from the
    files alone (so a user re-running the evaluation gets the same numbers)."""
    d = slam_run
    js = json.loads((d / "est.json").read_text())
    err = trajectory_errors(Trajectory.read(d / "est.txt"),
                            Trajectory.read(d / "airy_true_trajectory.txt")).to_dict()
    for key in ("ate_rms_m", "final_error_m", "final_error_pct", "path_length_m"):
        assert js[key] == pytest.approx(err[key], rel=1e-6, abs=1e-9), key
    md = (d / "est_report.md").read_text()
    assert f"{js['ate_rms_m']:.3f}" in md and "kiss-icp" in md
    png = (d / "est.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_slam_cloud_is_the_placed_drive_and_control_is_observed_in_it(slam_run):
    d = slam_run
    est = Trajectory.read(d / "est.txt")
    truth = Trajectory.read(d / "prof_true_trajectory.txt")
    orig = laspy.read(d / "prof.laz")
    got = laspy.read(d / "mls.laz")
    assert len(got.x) == len(orig.x)
    xyz = np.stack([orig.x, orig.y, orig.z], 1)
    want = to_slam_frame(truth, est, xyz, np.asarray(orig.gps_time))
    # est.txt is written with 1 ns / 1 nm digits: agreement to the LAS scale.
    assert np.abs(np.stack([got.x, got.y, got.z], 1) - want).max() < 3e-4
    obs = np.genfromtxt(d / "mls_cp_observed.csv", delimiter=",", names=True, dtype=None,
                        encoding="utf-8")
    # Prisms every 25 m from 12.5 m: three (walls and crown) at 12.5 in a 5-14 m drive.
    assert len(obs) == 3 and all(str(i).startswith("P00") for i in obs["id"])
    assert np.all((obs["time"] > truth.start_s) & (obs["time"] < truth.end_s))


@pytest.mark.slow
def test_genz_icp_runs_behind_the_same_interface(slam_run, tmp_path):
    d = slam_run
    assert main(["slam", str(d / "airy.laz"), "-o", str(tmp_path / "g.txt"), "--odometry",
                 "genz-icp", "--truth", str(d / "airy_true_trajectory.txt"), "--quiet"]) == 0
    js = json.loads((tmp_path / "g.json").read_text())
    assert js["odometry"] == "genz-icp" and js["final_error_m"] < 0.2
    assert (tmp_path / "g.txt").read_text() != (d / "est.txt").read_text()


# ------------------------------------------------------------------ bad input
def _fails(argv, capsys, match, folder):
    before = set(folder.iterdir())
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tunnelsim: error:") and match in err[0], err
    assert set(folder.iterdir()) == before


def test_slam_refuses_bad_input_in_one_line_and_writes_nothing(drive_dir, tmp_path, capsys):
    d = drive_dir
    # A cloud without per-point times or sensor-frame fields (a compact station file).
    assert main(["scan", "--mesh", str(d / "t.ply"), "--chainage", "10", "--resolution",
                 "preview", "-o", str(tmp_path / "st.laz"), "--quiet"]) == 0
    _fails(["slam", str(tmp_path / "st.laz"), "-o", str(tmp_path / "e.txt")], capsys,
           "sensor-frame fields", tmp_path)
    # An unknown output extension: refused before the odometry runs.
    _fails(["slam", str(d / "airy.laz"), "-o", str(tmp_path / "e.las")], capsys,
           "trajectory file", tmp_path)
    _fails(["slam", str(d / "airy.laz"), "-o", str(tmp_path / "e.txt"), "--cloud",
            str(tmp_path / "c.ply")], capsys, "--cloud as .las/.laz", tmp_path)
    _fails(["slam", str(d / "airy.laz"), "-o", str(tmp_path / "e.txt"), "--control",
            str(d / "t.json")], capsys, "--truth and --cloud", tmp_path)
    # A drive too short for SLAM: 0.5 s of Airy = 5 frames.
    assert main(["drive", "--mesh", str(d / "t.ply"), "--along", "centreline", "--speed",
                 "1", "--chainage", "5,5.5", "--fields", "full", "-o",
                 str(tmp_path / "short.laz"), "--quiet"]) == 0
    _fails(["slam", str(tmp_path / "short.laz"), "-o", str(tmp_path / "e.txt"), "--cloud",
            str(tmp_path / "c.laz")], capsys, "whole scan frames", tmp_path)


@pytest.mark.slow
def test_slam_reads_a_ros2_bag_as_the_laz(drive_dir, tmp_path, capsys):
    """The same drive as a ROS 2 bag (rslidar_sdk layout, float32 sensor points, mount
    in /tf_static) gives the trajectory the LAZ gives, within the odometry's own
    sensitivity: its voxel filter keeps the first point of each voxel, so float32
    rounding and the bag's point order pick other points (measured: 2 cm apart at
    most over 9 m); re-placing a bag's clouds is refused (sensor-frame points only)."""
    pytest.importorskip("rosbags")
    d = drive_dir
    assert main(["drive", "--mesh", str(d / "t.ply"), "--along", "centreline", "--speed", "3",
                 "--chainage", "5,14", "--standstill", "1", "-o", str(tmp_path / "a.mcap"),
                 "--quiet"]) == 0
    bag = open_drive(tmp_path / "a.mcap")
    assert bag.kind == "bag" and bag.mount_recorded and bag.topic == "/rslidar_points"
    truth = str(d / "airy_true_trajectory.txt")
    assert main(["slam", str(tmp_path / "a.mcap"), "-o", str(tmp_path / "b.txt"), "--truth",
                 truth, "--quiet"]) == 0
    assert main(["slam", str(d / "airy.laz"), "-o", str(tmp_path / "l.txt"), "--truth",
                 truth, "--quiet"]) == 0
    b, la = Trajectory.read(tmp_path / "b.txt"), Trajectory.read(tmp_path / "l.txt")
    t = b.times[(b.times > la.start_s) & (b.times < la.end_s)]
    assert len(t) > 30
    assert np.abs(b.interpolate(t)[0] - la.interpolate(t)[0]).max() < 0.05
    _fails(["slam", str(tmp_path / "a.mcap"), "-o", str(tmp_path / "c.txt"), "--cloud",
            str(tmp_path / "c.laz")], capsys, "--place DRIVE.laz", tmp_path)


def test_every_drive_writes_the_truth_it_drove(drive_dir, tmp_path):
    """A drive on the user's own trajectory writes the truth beside the cloud too (the
    input, trimmed to --duration), and world = pose(t) o mount o sensor point holds from
    the files alone to 0.1 mm (the LAS scale)."""
    d = drive_dir
    t = np.linspace(0.0, 3.0, 31)
    own = Trajectory(t, np.stack([8.0 + t, 0.1 * np.sin(t), 1.2 + 0 * t], 1),
                     Rotation.from_euler("z", 0.05 * t[:, None]))
    own.write(tmp_path / "own.csv")
    assert main(["drive", "--mesh", str(d / "t.ply"), "--sensor", "velodyne_vlp16",
                 "--trajectory", str(tmp_path / "own.csv"), "--lever", "0.2,0,0.3",
                 "--duration", "2", "--fields", "full", "-o", str(tmp_path / "v.laz"),
                 "--quiet"]) == 0
    truth = Trajectory.read(tmp_path / "v_true_trajectory.txt")
    assert truth.start_s == 0.0 and truth.end_s == pytest.approx(2.0)
    np.testing.assert_allclose(truth.positions[:-1], own.positions[:len(truth) - 1],
                               atol=1e-9)
    drive = open_drive(tmp_path / "v.laz")
    las = laspy.read(tmp_path / "v.laz")
    pos, mat = truth.sensor_matrices(np.asarray(las.gps_time), drive.mount)
    s = np.stack([las.sensor_x, las.sensor_y, las.sensor_z], 1)
    world = pos + np.einsum("nij,nj->ni", mat, s)
    assert np.abs(world - np.stack([las.x, las.y, las.z], 1)).max() < 1e-4 + 1e-9
