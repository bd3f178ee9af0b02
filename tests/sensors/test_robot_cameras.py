"""Camera links in the robot's URDF (issue 35): a drive's ``<out>_robot.urdf`` and
``gazebo --camera``'s ``robot.urdf`` hold each camera's body frame (fixed in
base_link by the mount) and optical frame (REP 103's rpy -pi/2, 0, -pi/2), on the files
the user gets.

References: the URDF parsed with ``xml.etree`` and its joints composed in
``tests.survey.export.test_robot_description.urdf_chain`` (rpy written out with
cos/sin, not through the writer's code); the bag's ``/tf_static`` read back with
rosbags; the ``--camera-mount`` given (rotation built here from the degrees); REP 103's
optical axes as a literal matrix; libsdformat's own resolution of the Gazebo camera's
pose (tests/survey/export/sdf/camera_check.cpp, skipped without libsdformat).
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from sensors import Mount
from sensors.camera import load_camera
from sensors.errors import PlatformError
from sensors.robot import CameraLink, RobotDescription, camera_link
from survey.cli.main import main
from survey.world.alignment import Alignment, straight
from survey.world.generator import make_tunnel
from survey.world.profiles import horseshoe
from tests.survey.export.test_gazebo_camera import camera_check  # noqa: F401 (fixture)
from tests.survey.export.test_robot_description import _rpy_matrix, urdf_chain
from tests.survey.workflows.test_drive_camera import COLOR, DEPTH
from tests.survey.workflows.test_drive_workflow import SENSOR

rosbags = pytest.importorskip("rosbags", reason="rosbags is in the test extra")
from rosbags.highlevel import AnyReader  # noqa: E402

#: REP 103: the optical axes (x right, y down, z forward) as columns in the body frame.
BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
MOUNT = (0.12, -0.03, 0.21, 3.0, -7.0, 11.0)     # X,Y,Z m, roll, pitch, yaw deg


def _mount_matrix(mount) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = _rpy_matrix(*(math.radians(a) for a in mount[3:]))
    m[:3, 3] = mount[:3]
    return m


def _optical(m: np.ndarray) -> np.ndarray:
    out = m.copy()
    out[:3, :3] = m[:3, :3] @ BODY_FROM_OPTICAL
    return out


def _tf_matrix(tf) -> np.ndarray:
    q = tf.rotation
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    m[:3, 3] = [tf.translation.x, tf.translation.y, tf.translation.z]
    return m


@pytest.fixture(scope="module")
def small_tunnel(tmp_path_factory):
    """A 12 m horseshoe tunnel along x (floor at z = 0)."""
    t = make_tunnel(Alignment([straight(12.0)]), horseshoe(5.0), edge_length_m=0.5,
                    roughness_rms_m=0.0)
    path = tmp_path_factory.mktemp("robotcam") / "t.ply"
    t.write(path)
    return path


def _trajectory(path: Path) -> Path:
    t = np.round(np.arange(21) * 0.01, 2)
    rows = [f"{ti:.2f} {4 + ti:.6f} 0.2 1.5 0 0 0 1" for ti in t]
    path.write_text("# t x y z qx qy qz qw\n" + "\n".join(rows) + "\n")
    return path


def _files(tmp_path: Path, **texts: str) -> dict[str, Path]:
    out = {}
    for name, text in texts.items():
        p = tmp_path / f"{name}.toml"
        p.write_text(text)
        out[name] = p
    return out


def test_drive_bag_urdf_camera_frames_equal_tf_static(small_tunnel, tmp_path):
    """A drive into a bag with a RealSense-named colour and depth camera: the URDF
    holds camera_link once and both optical frames; each composed chain equals the
    bag's /tf_static (base_link -> camera_link -> optical frame) and the mount given
    with REP 103's axes, to 1e-12; the optical joints' rpy are -pi/2, 0, -pi/2."""
    f = _files(tmp_path, sensor=SENSOR, color=COLOR, depth=DEPTH)
    bag = tmp_path / "d.mcap"
    assert main(["drive", "--mesh", str(small_tunnel), "--sensor", str(f["sensor"]),
                 "--trajectory", str(_trajectory(tmp_path / "tr.txt")), "--duration",
                 "0.2", "--camera", str(f["color"]), "--camera", str(f["depth"]),
                 "--camera-mount", ",".join(map(str, MOUNT)), "--no-noise", "-o",
                 str(bag), "--quiet"]) == 0
    urdf = tmp_path / "d_robot.urdf"
    root = ET.parse(urdf).getroot()
    links = [e.get("name") for e in root.findall("link")]
    assert links.count("camera_link") == 1
    assert {"camera_color_optical_frame", "camera_depth_optical_frame"} <= set(links)
    for kind in ("color", "depth"):
        (j,) = [j for j in root.findall("joint")
                if j.find("child").get("link") == f"camera_{kind}_optical_frame"]
        assert j.get("type") == "fixed" and j.find("parent").get("link") == "camera_link"
        np.testing.assert_allclose([float(x) for x in j.find("origin").get("rpy").split()],
                                   [-math.pi / 2, 0.0, -math.pi / 2], rtol=0, atol=1e-12)
    with AnyReader([bag]) as r:
        cons = [c for c in r.connections if c.topic == "/tf_static"]
        (static,) = [r.deserialize(raw, c.msgtype) for c, _, raw in r.messages(cons)]
    tf = {(x.header.frame_id, x.child_frame_id): _tf_matrix(x.transform)
          for x in static.transforms}
    link = urdf_chain(urdf, "camera_link")
    np.testing.assert_allclose(link, tf[("base_link", "camera_link")], rtol=0, atol=1e-12)
    np.testing.assert_allclose(link, _mount_matrix(MOUNT), rtol=0, atol=1e-12)
    for kind in ("color", "depth"):
        frame = f"camera_{kind}_optical_frame"
        got = urdf_chain(urdf, frame)
        np.testing.assert_allclose(got, tf[("base_link", "camera_link")]
                                   @ tf[("camera_link", frame)], rtol=0, atol=1e-12)
        np.testing.assert_allclose(got, _optical(_mount_matrix(MOUNT)), rtol=0, atol=1e-12)
    # The lidar's and the IMU's joints are still there.
    assert {"mast_link", "imu_link", "base_link"} <= set(links)


def test_drive_folder_urdf_camera_frames_equal_camera_info(small_tunnel, tmp_path):
    """A drive into a point file with a camera that is not a RealSense: the URDF names
    its frames NAME_link and NAME_optical_frame (the image_pipeline names the folder's
    frames use), at the default mount when none is given: the optical frame equals the
    folder's camera_info.json ``base_from_optical`` (1e-12), 0.1 m below the lidar."""
    other = DEPTH.replace('vendor = "Intel"', 'vendor = "Acme"').replace(
        'model = "RealSense test depth"', 'model = "ToF test"')
    f = _files(tmp_path, sensor=SENSOR, depth=other)
    out = tmp_path / "d.laz"
    assert main(["drive", "--mesh", str(small_tunnel), "--sensor", str(f["sensor"]),
                 "--trajectory", str(_trajectory(tmp_path / "tr.txt")), "--duration",
                 "0.1", "--camera", str(f["depth"]), "--no-noise", "-o", str(out),
                 "--quiet"]) == 0
    urdf = tmp_path / "d_robot.urdf"
    info = json.loads((tmp_path / "d_cameras" / "test_depth" / "camera_info.json")
                      .read_text())
    got = urdf_chain(urdf, "test_depth_optical_frame")
    np.testing.assert_allclose(got, np.asarray(info["base_from_optical"]), rtol=0,
                               atol=1e-12)
    body = urdf_chain(urdf, "test_depth_link")
    lidar = next(j.find("child").get("link") for j in ET.parse(urdf).getroot()
                 .findall("joint") if j.get("name") == "sensor_joint")
    np.testing.assert_allclose(body[:3, 3], urdf_chain(urdf, lidar)[:3, 3] - [0, 0, 0.1],
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(body[:3, :3], np.eye(3), rtol=0, atol=1e-12)


def test_gazebo_camera_urdf_is_where_libsdformat_puts_the_camera(small_tunnel, tmp_path,
                                                                 camera_check):
    """``gazebo --camera``: robot.urdf's camera_link and optical frame equal the camera
    sensor's pose and the optical <frame>'s pose as libsdformat resolves them in the
    model frame (base_link; 1e-9 m, 1e-9 rad: SDF poses are written with 15 digits);
    the README names them; a world without a camera has no camera frames in its URDF."""
    import subprocess

    assert main(["gazebo", "--mesh", str(small_tunnel), "--camera", "realsense_d435_depth",
                 "-o", str(tmp_path / "w"), "--quiet"]) == 0
    assert main(["gazebo", "--mesh", str(small_tunnel), "-o", str(tmp_path / "plain"),
                 "--quiet"]) == 0
    r = subprocess.run([str(camera_check), str(tmp_path / "w" / "world.sdf"),
                        str(tmp_path / "w" / "models")], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr

    def pose(prefix):
        (d,) = [dict(kv.split("=", 1) for kv in ln.split()[1:])
                for ln in r.stdout.splitlines() if ln.startswith(prefix + " ")]
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat([float(d[k]) for k in ("qx", "qy", "qz", "qw")]
                                       ).as_matrix()
        m[:3, 3] = [float(d[k]) for k in "xyz"]
        return d, m

    _, sensor = pose("camera")
    fr, frame = pose("frame")
    assert fr["name"] == "camera_depth_optical_frame"
    urdf = tmp_path / "w" / "robot.urdf"
    np.testing.assert_allclose(urdf_chain(urdf, "camera_link"), sensor, rtol=0, atol=1e-9)
    np.testing.assert_allclose(urdf_chain(urdf, "camera_depth_optical_frame"), frame,
                               rtol=0, atol=1e-9)
    assert "robot.urdf: base_link -> camera_link -> camera_depth_optical_frame" in \
        (tmp_path / "w" / "README.txt").read_text()
    plain = ET.parse(tmp_path / "plain" / "robot.urdf").getroot()
    assert not [e for e in plain.findall("link") if "camera" in e.get("name")]


@given(xyz=st.lists(st.floats(-1, 1), min_size=3, max_size=3),
       rpy=st.lists(st.floats(-3.1, 3.1), min_size=3, max_size=3),
       h=st.floats(0.0, 2.0))
@settings(max_examples=40, deadline=None)
def test_urdf_camera_chain_is_the_mount(tmp_path_factory, xyz, rpy, h):
    """Any mount: the URDF's composed joints to the body and optical frames equal the
    mount and the mount with REP 103's axes (1e-12), and ``base_to_camera`` says the
    same."""
    mount = Mount(tuple(xyz), Rotation.from_euler("xyz", rpy))
    robot = RobotDescription("r", "lidar", h, Mount(), cameras=(
        CameraLink("cam_link", "cam_optical_frame", mount),))
    path = tmp_path_factory.mktemp("u") / "r.urdf"
    robot.write_urdf(path)
    want = np.eye(4)
    want[:3, :3] = _rpy_matrix(*rpy)
    want[:3, 3] = xyz
    np.testing.assert_allclose(urdf_chain(path, "cam_link"), want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(urdf_chain(path, "cam_optical_frame"), _optical(want),
                               rtol=0, atol=1e-12)
    p, r = robot.base_to_camera("cam_optical_frame")
    np.testing.assert_allclose(p, xyz, rtol=0, atol=0)
    np.testing.assert_allclose(r.as_matrix(), _optical(want)[:3, :3], rtol=0, atol=1e-12)


def test_camera_frames_are_checked():
    """Two mounts for one body frame, a camera frame named as the robot's own, and an
    optical frame given twice are refused; two streams of one device share a link."""
    a = Mount((0.1, 0.0, 0.2))
    b = Mount((0.1, 0.0, 0.3))
    color, depth = load_camera("realsense_d435_color"), load_camera("realsense_d435_depth")
    same = Mount((0.1, 0, 0.2))
    robot = RobotDescription("r", "lidar",
                             cameras=(camera_link(color, a), camera_link(depth, same)))
    assert robot.camera_frames() == ("camera_link", "camera_color_optical_frame",
                                     "camera_depth_optical_frame")
    assert robot.urdf().count('<link name="camera_link"/>') == 1
    with pytest.raises(PlatformError, match="one place for the camera frame 'camera_link'"):
        RobotDescription("r", "lidar",
                         cameras=(camera_link(color, a), camera_link(depth, b)))
    with pytest.raises(PlatformError, match="other than the robot's own"):
        RobotDescription("r", "lidar", cameras=(CameraLink("imu_link", "x_optical", a),))
    with pytest.raises(PlatformError, match="optical frame once"):
        RobotDescription("r", "lidar",
                         cameras=(camera_link(color, a), camera_link(color, a)))
    with pytest.raises(PlatformError, match="Expected a camera frame of the robot"):
        robot.base_to_camera("nope")
