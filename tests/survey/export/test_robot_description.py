"""One robot description for a drive and its bag (issue 30), on the files the user gets:
``<out>_robot.urdf`` parsed with ``xml.etree`` and its joints composed here (URDF rpy:
R = Rz(yaw) Ry(pitch) Rx(roll), written out with cos/sin, not through the writer's
code), the bag's ``/tf_static``, ``/tf``, ``/imu/data_raw`` and ``/odom`` read back with
rosbags, ``<out>_base_link_trajectory.txt`` against the mesh by brute-force ray casts
(``tests.naive``), and the IMU at its lever arm against the rigid-body formula
a = omega x (omega x r) of a robot turning on the spot.
"""

from __future__ import annotations

import ast
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from sensors import Mount, Trajectory
from sensors.errors import PlatformError
from sensors.imu import ImuModel, WheelOdometryModel
from sensors.platform_spec import list_platforms, load_platform
from sensors.robot import RobotDescription
from survey.cli.main import main
from tests.naive import naive_cast
from tests.sensors.test_route import bent_tube
from tests.survey.cli.test_drive_platform import SENSOR, _write_mesh

pytest.importorskip("rosbags", reason="rosbags is in the test extra")
from rosbags.highlevel import AnyReader  # noqa: E402

LEVER = (0.05, -0.02, 0.1)
G = 9.80665


def _rpy_matrix(r, p, y):
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                              math.cos(y), math.sin(y))
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def urdf_chain(path, child):
    """base_link -> ``child`` (4 x 4) by composing the URDF's joints from the root."""
    root = ET.parse(path).getroot()
    assert root.tag == "robot"
    links = {e.get("name") for e in root.findall("link")}
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}
    assert child in links and "base_link" in links
    m = np.eye(4)
    frame = child
    while frame != "base_link":
        j = joints[frame]
        o = j.find("origin")
        t = np.eye(4)
        t[:3, :3] = _rpy_matrix(*map(float, o.get("rpy").split()))
        t[:3, 3] = [float(x) for x in o.get("xyz").split()]
        m = t @ m
        frame = j.find("parent").get("link")
    return m


def _quat_matrix(q):
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _angle_deg(a, b):
    c = (np.trace(a.T @ b) - 1) / 2
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def _bag(path, topics):
    out = {t: [] for t in topics}
    with AnyReader([Path(path)]) as r:
        cons = [c for c in r.connections if c.topic in topics]
        for c, t, raw in r.messages(connections=cons):
            out[c.topic].append(r.deserialize(raw, c.msgtype))
    return out


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("robot")
    v, f = bent_tube()
    mesh = _write_mesh(tmp / "bend.ply", v, f)
    (tmp / "s.toml").write_text(SENSOR)
    assert main(["drive", "--mesh", mesh, "--sensor", str(tmp / "s.toml"), "--along", "auto",
                 "--speed", "1", "--mount", "down", "--lever", ",".join(map(str, LEVER)),
                 "--duration", "3", "-o", str(tmp / "d.mcap"), "--quiet"]) == 0
    return tmp, v, f


def test_urdf_equals_the_bags_tf_static(drive):
    """base_link -> sensor and base_link -> imu_link: the URDF's composed joints equal
    the bag's /tf_static (1 mm, 0.01 deg) and the drive's options (mast 0.5 m plus
    --lever, --mount down: z of the sensor along -z of the base)."""
    tmp, _, _ = drive
    msgs = _bag(tmp / "d.mcap", ["/tf_static", "/imu/data_raw"])
    static = {tf.child_frame_id: tf for m in msgs["/tf_static"] for tf in m.transforms}
    sensor_frame = next(k for k in static if k not in ("odom", "imu_link"))
    assert static[sensor_frame].header.frame_id == "base_link"
    for frame in (sensor_frame, "imu_link"):
        m = urdf_chain(tmp / "d_robot.urdf", frame)
        tf = static[frame].transform
        got = np.array([tf.translation.x, tf.translation.y, tf.translation.z])
        assert np.abs(got - m[:3, 3]).max() <= 1e-3
        assert _angle_deg(_quat_matrix(tf.rotation), m[:3, :3]) <= 0.01
    m = urdf_chain(tmp / "d_robot.urdf", sensor_frame)
    np.testing.assert_allclose(m[:3, 3], np.add(LEVER, [0, 0, 0.5]), atol=1e-6)
    assert m[:3, :3] @ [0, 0, 1] == pytest.approx([0, 0, -1], abs=1e-6)
    robot = load_platform("ground_robot")
    np.testing.assert_allclose(urdf_chain(tmp / "d_robot.urdf", "imu_link")[:3, 3],
                               robot.imu_xyz_m, atol=1e-9)
    assert msgs["/imu/data_raw"][0].header.frame_id == "imu_link"


def test_base_link_is_on_the_floor_and_the_sensor_did_not_move(drive):
    """base_link (its trajectory file) lies on the floor: a ray cast down from 0.1 m
    above it meets the mesh 0.1 m below (the horseshoe's flat floor; 2 mm); the sensor
    placed by base_link o URDF is where the platform frame o mount puts it (1e-6 m);
    the bag's map -> odom -> base_link is the base_link file (1e-6 m)."""
    tmp, v, f = drive
    base = Trajectory.read(tmp / "d_base_link_trajectory.txt")
    top = Trajectory.read(tmp / "d_true_trajectory.txt")
    p = base.positions[::5]
    up = base.rotations[::5].apply([0.0, 0.0, 0.1])
    t = naive_cast(v, f, p + up, -up / 0.1)[0]
    np.testing.assert_allclose(t, 0.1, atol=2e-3)
    frames = _bag(tmp / "d.mcap", ["/tf_static"])["/tf_static"][0].transforms
    sensor_frame = next(tf.child_frame_id for tf in frames
                        if tf.child_frame_id not in ("odom", "imu_link"))
    m = urdf_chain(tmp / "d_robot.urdf", sensor_frame)
    mount = Mount.pointing_down(LEVER)
    world_a = top.positions + top.rotations.apply(mount.lever_arm_m)
    world_b = base.positions + base.rotations.apply(m[:3, 3])
    np.testing.assert_allclose(world_a, world_b, atol=1e-6)
    msgs = _bag(tmp / "d.mcap", ["/tf"])["/tf"]
    origin = next(np.array([tf.transform.translation.x, tf.transform.translation.y,
                            tf.transform.translation.z]) for tf in frames
                  if tf.child_frame_id == "odom")
    tf = msgs[50].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("odom", "base_link")
    stamp = tf.header.stamp.sec + tf.header.stamp.nanosec * 1e-9
    got = origin + [tf.transform.translation.x, tf.transform.translation.y,
                    tf.transform.translation.z]
    np.testing.assert_allclose(got, base.interpolate([stamp])[0][0], atol=1e-6)


def test_launch_file_and_wheel_odometry(drive):
    """The launch file is Python naming the URDF beside it and robot_state_publisher;
    /odom (nav_msgs/Odometry, odom -> base_link) starts at the true pose and stays
    within a few sigma of the model's random walk of the truth over the 3 s."""
    tmp, _, _ = drive
    text = (tmp / "d_robot.launch.py").read_text()
    ast.parse(text)
    assert "'d_robot.urdf'" in text and "robot_state_publisher" in text
    odom = _bag(tmp / "d.mcap", ["/odom"])["/odom"]
    assert len(odom) >= 290 and odom[0].child_frame_id == "base_link"
    base = Trajectory.read(tmp / "d_base_link_trajectory.txt")
    tf_static = _bag(tmp / "d.mcap", ["/tf_static"])["/tf_static"][0].transforms
    origin = next(np.array([tf.transform.translation.x, tf.transform.translation.y])
                  for tf in tf_static if tf.child_frame_id == "odom")
    xy = np.array([[o.pose.pose.position.x, o.pose.pose.position.y] for o in odom])
    t = np.array([o.header.stamp.sec + o.header.stamp.nanosec * 1e-9 for o in odom])
    truth = base.interpolate(t)[0][:, :2] - origin
    np.testing.assert_allclose(xy[0], truth[0], atol=1e-9)
    err = np.linalg.norm(xy - truth, axis=1)
    # Distance driven d <= 3 m: sigma of the along-track walk sqrt(1e-4 d) plus the 1 %
    # scale error; 5 sigma of both (a seeded draw; the bound is loose on purpose).
    assert err.max() <= 5 * (math.sqrt(1e-4 * 3) + 0.01 * 3)
    assert err.max() > 0                                     # the noise is there


def _spin_bag(path, imu_mount, odo, seed=0):
    """A robot turning on the spot at 1 rad/s (trajectory at 200 Hz), IMU noise off."""
    from sensors import load_sensor as load
    from sensors.bag import RosbagStream

    t = np.arange(0, 2.0001, 0.005)
    traj = Trajectory(t, np.tile([10.0, 5.0, 1.0], (len(t), 1)),
                      Rotation.from_euler("z", t[:, None]))
    quiet = ImuModel(gyro_noise_density=0, gyro_random_walk=0, accel_noise_density=0,
                     accel_random_walk=0, gyro_bias_sigma=0, accel_bias_sigma=0)
    with RosbagStream(path, load("velodyne_vlp16"), single_file=True, trajectory=traj,
                      span_s=(0.0, 2.0), imu=quiet, imu_mount=imu_mount, seed=seed,
                      wheel_odometry=odo):
        pass
    return _bag(path, ["/imu/data_raw", "/odom", "/tf_static"])


def test_imu_at_its_lever_arm_sees_the_centripetal_acceleration(tmp_path):
    """At r = 0.3 m ahead of the axis of a 1 rad/s turn on the spot, a noiseless IMU
    yawed by 90 deg reads the centripetal omega^2 r = 0.3 m/s^2 toward the axis (its
    own +y: base_link -x), gravity's reaction +G on z and the yaw rate 1 rad/s."""
    mount = Mount((0.3, 0.0, 0.1), Rotation.from_euler("z", 90, degrees=True))
    msgs = _spin_bag(tmp_path / "s.mcap", mount, None)
    imu = msgs["/imu/data_raw"][50:-50]
    acc = np.array([[m.linear_acceleration.x, m.linear_acceleration.y,
                     m.linear_acceleration.z] for m in imu])
    gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                     for m in imu])
    np.testing.assert_allclose(acc, np.tile([0.0, 0.3, G], (len(acc), 1)), atol=1e-3)
    np.testing.assert_allclose(gyro, np.tile([0, 0, 1.0], (len(acc), 1)), atol=1e-6)
    static = {tf.child_frame_id: tf for tf in msgs["/tf_static"][0].transforms}
    assert static["imu_link"].transform.translation.x == pytest.approx(0.3)


def test_wheel_odometry_is_seeded_and_exact_without_noise(tmp_path):
    """Without noise /odom is the true heading (1 rad/s turn: yaw = t); the same seed
    gives the same messages, another seed others."""
    exact = WheelOdometryModel(0, 0, 0, 0, 0)
    msgs = _spin_bag(tmp_path / "a.mcap", None, exact)["/odom"]
    yaw = [2 * math.atan2(m.pose.pose.orientation.z, m.pose.pose.orientation.w)
           for m in msgs]
    t = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in msgs])
    np.testing.assert_allclose(np.unwrap(yaw), t, atol=1e-9)
    noisy = [[m.pose.pose.orientation.z for m in _spin_bag(tmp_path / f"{k}.mcap", None,
                                                           WheelOdometryModel(),
                                                           seed=s)["/odom"]]
             for k, s in (("b", 1), ("c", 1), ("d", 2))]
    assert noisy[0] == noisy[1] and noisy[0] != noisy[2]


@given(xyz=st.lists(st.floats(-1, 1), min_size=3, max_size=3),
       rpy=st.lists(st.floats(-3.1, 3.1), min_size=3, max_size=3),
       h=st.floats(0.0, 2.0))
@settings(max_examples=40, deadline=None)
def test_urdf_joint_chain_is_the_description(tmp_path_factory, xyz, rpy, h):
    """Any mount and mast height: the URDF's composed joints equal base_to_sensor
    (1e-7 m, 1e-5 deg), and base_trajectory o base_to_sensor = platform o mount."""
    mount = Mount(tuple(xyz), Rotation.from_euler("xyz", rpy))
    robot = RobotDescription("r", "lidar", h, mount)
    path = tmp_path_factory.mktemp("u") / "r.urdf"
    robot.write_urdf(path)
    m = urdf_chain(path, "lidar")
    p, r = robot.base_to_sensor()
    assert np.abs(m[:3, 3] - p).max() <= 1e-7
    assert _angle_deg(m[:3, :3], r.as_matrix()) <= 1e-5
    top = Trajectory([0.0, 1.0], [[1.0, 2, 3], [2.0, 2, 3]],
                     Rotation.from_euler("xyz", [[0.1, 0.2, 0.3], [0.0, -0.2, 1.0]]))
    base = robot.base_trajectory(top)
    np.testing.assert_allclose(base.positions + base.rotations.apply(p),
                               top.positions + top.rotations.apply(mount.lever_arm_m),
                               atol=1e-9)


def test_platform_mounts_are_validated(tmp_path):
    """[mounts] is optional; when given, its keys are checked like every table."""
    src = Path(load_platform("ground_robot").path).read_text()
    for name in list_platforms():
        load_platform(name)
    bad = tmp_path / "bad.toml"
    bad.write_text(src.replace("imu_rpy_deg", "imu_rpy"))
    with pytest.raises(PlatformError, match=r"unknown key `imu_rpy` \(did you mean `imu_rpy_deg`"):
        load_platform(bad)
    bad.write_text(src.replace("imu_xyz_m = [0.0, 0.0, 0.10]", "imu_xyz_m = [0.0, 0.1]"))
    with pytest.raises(PlatformError, match="3 finite numbers"):
        load_platform(bad)
    bad.write_text(src.replace("wheel_radius_m = 0.045", ""))
    with pytest.raises(PlatformError, match="wheel_radius_m"):
        load_platform(bad)
    old = tmp_path / "old.toml"
    old.write_text(src.split("[mounts]")[0] + "[limits]" + src.split("[limits]")[1])
    spec = load_platform(old)
    assert spec.imu_xyz_m is None
    robot = RobotDescription.from_platform(spec, "lidar")
    assert robot.base_to_imu()[0] == pytest.approx([0, 0, spec.mast_height_m])


def test_drive_cli_speed_message_and_output_help(tmp_path, capsys):
    """--along auto without --speed names --speed, not 'got neither'; -o help names
    bags."""
    v, f = bent_tube()
    mesh = _write_mesh(tmp_path / "b.ply", v, f)
    assert main(["drive", "--mesh", mesh, "--along", "auto", "-o",
                 str(tmp_path / "x.laz")]) == 2
    err = capsys.readouterr().err
    assert "--speed" in err and "neither" not in err and len(err.strip().splitlines()) == 1
    with pytest.raises(SystemExit):
        main(["drive", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert ".mcap" in out and "rosbag2 folder" in out


def _sdf_pose(text):
    x, y, z, r, p, yw = (float(v) for v in text.split())
    m = np.eye(4)
    m[:3, :3] = _rpy_matrix(r, p, yw)
    m[:3, 3] = [x, y, z]
    return m


def test_gazebo_world_is_the_drives_robot(drive):
    """The Gazebo world of the drive's mesh: its robot.urdf, the SDF sensor pose
    (chassis link pose o sensor pose, SDF rpy composed here) and the IMU's equal the
    URDF's base_link -> sensor / imu_link (1 mm, 0.01 deg); the wheels are the
    platform's track apart; the local origin is the bag's map -> odom; the README's
    sensor frame exists in the SDF."""
    tmp, _, _ = drive
    w = tmp / "w"
    assert main(["gazebo", "--mesh", str(tmp / "bend.ply"), "--sensor", "velodyne_vlp16",
                 "--mount", "down", "-o", str(w), "--quiet"]) == 0
    launch = (w / "robot.launch.py").read_text()
    ast.parse(launch)
    assert "'robot.urdf'" in launch
    root = ET.parse(w / "world.sdf").getroot()
    origin = -np.array(root.find("world/frame[@name='map_origin']/pose").text.split()[:3],
                       dtype=float)
    model = root.find("world/model[@name='robot']")
    chassis = model.find("link[@name='chassis']")
    lidar = chassis.find("sensor[@type='gpu_lidar']")
    imu = chassis.find("sensor[@type='imu']")
    link = _sdf_pose(chassis.find("pose").text)
    for sdf, frame in ((lidar, "velodyne"), (imu, "imu_link")):
        m = link @ _sdf_pose(sdf.find("pose").text)
        u = urdf_chain(w / "robot.urdf", frame)
        assert np.abs(m[:3, 3] - u[:3, 3]).max() <= 1e-3
        assert _angle_deg(m[:3, :3], u[:3, :3]) <= 0.01
    u = urdf_chain(w / "robot.urdf", "velodyne")
    np.testing.assert_allclose(u[:3, 3], [0, 0, 0.5], atol=1e-9)          # the mast
    assert u[:3, :3] @ [0, 0, 1] == pytest.approx([0, 0, -1], abs=1e-9)   # --mount down
    ys = sorted(float(model.find(f"link[@name='{s}_wheel']/pose").text.split()[1])
                for s in ("left", "right"))
    assert ys[1] - ys[0] == pytest.approx(load_platform("ground_robot").track_m)
    static = _bag(tmp / "d.mcap", ["/tf_static"])["/tf_static"][0].transforms
    odom = next(tf.transform.translation for tf in static if tf.child_frame_id == "odom")
    np.testing.assert_allclose(origin, [odom.x, odom.y, odom.z], atol=1e-6)
    readme = (w / "README.txt").read_text()
    assert f"robot::chassis::{lidar.get('name')}" in readme
    assert "robot::chassis::lidar," not in readme


def test_libsdformat_places_the_sensors_where_the_urdf_does(drive, sdf_check):
    """libsdformat's own resolution of each sensor's pose in the model frame (the
    checker's sensor_pose lines) equals robot.urdf's base_link -> sensor and -> imu_link
    (1 mm, 0.01 deg): the world's robot is the drive's."""
    from sensors import load_sensor
    from survey.export.gazebo import export_gazebo
    from tests.survey.export.test_gazebo import _check

    tmp, _, _ = drive
    export_gazebo(tmp / "bend.ply", load_sensor("ouster_os1_64"), tmp / "wl")
    rc, out = _check(sdf_check, tmp / "wl")
    assert rc == 0, out
    poses = {}
    for line in out.splitlines():
        if line.startswith("sensor_pose "):
            kv = dict(x.split("=", 1) for x in line.split()[1:])
            poses[kv["name"]] = kv
    root = ET.parse(tmp / "wl" / "world.sdf").getroot()
    chassis = root.find("world/model[@name='robot']/link[@name='chassis']")
    names = {"imu_link": chassis.find("sensor[@type='imu']").get("name"),
             "os_sensor": chassis.find("sensor[@type='gpu_lidar']").get("name")}
    for frame, name in names.items():
        kv = poses[name]
        q = type("Q", (), {k: float(kv["q" + k]) for k in "wxyz"})
        u = urdf_chain(tmp / "wl" / "robot.urdf", frame)
        got = np.array([float(kv[k]) for k in "xyz"])
        assert np.abs(got - u[:3, 3]).max() <= 1e-3
        assert _angle_deg(_quat_matrix(q), u[:3, :3]) <= 0.01
