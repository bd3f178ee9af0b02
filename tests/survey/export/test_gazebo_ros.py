"""Gazebo worlds for both lines (issue 22) and the robot at the route's start (issue 20):
each flavour validates with libsdformat, names its own plugins and messages, carries the
IMU with the bag's noise model, the ground-truth publishers and a bridge whose every
Gazebo topic the world publishes (derived from the SDF the way Gazebo names topics);
laser_retro, the origin frame, the robot's start on the found route, bad input."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml  # PyYAML: installed with evo (test extra); parses the bridge file

from sensors import load_sensor
from sensors.imu import DEFAULT_IMU, ImuModel
from sensors.bag import IMU_TOPIC, ODOMETRY_TOPIC
from sensors.io.meshes import load_mesh
from sensors.route import find_route
from survey.cli.main import main
from survey.errors import GazeboExportError
from survey.export.gazebo import export_gazebo
from survey.export.gazebo_sdf import lidar_sdf
from survey.world.alignment import Alignment, straight
from survey.world.generator import make_tunnel
from survey.world.mesh import write_ply
from survey.world.profiles import horseshoe
from tests.survey.export.test_gazebo import _check


NS = "{https://github.com/tunnelsim}"
# The names each line documents (gz-sim / ign-gazebo CMake 'gz_add_system(<stem>)' and
# the plugin aliases; ros_gz_bridge READMEs for Jazzy and Humble), written out here
# rather than read from the module under test.
EXPECTED = {
    "harmonic": {"file": "gz-sim-{}-system", "cls": "gz::sim::systems::{}",
                 "msgs": "gz.msgs.", "env": "GZ_SIM_RESOURCE_PATH", "cmd": "gz sim",
                 "other": ("ignition", "IGN_")},
    "fortress": {"file": "ignition-gazebo-{}-system", "cls": "ignition::gazebo::systems::{}",
                 "msgs": "ignition.msgs.", "env": "IGN_GAZEBO_RESOURCE_PATH",
                 "cmd": "ign gazebo", "other": ("gz-sim", "gz::", "gz.msgs", "GZ_SIM")},
}
SYSTEMS = {"physics": "Physics", "user-commands": "UserCommands",
           "scene-broadcaster": "SceneBroadcaster", "sensors": "Sensors", "imu": "Imu",
           "diff-drive": "DiffDrive", "pose-publisher": "PosePublisher",
           "odometry-publisher": "OdometryPublisher"}


@pytest.fixture(scope="module")
def tunnels(tmp_path_factory):
    """A generated 20 m tunnel (PLY + JSON, reflectivity per face) and the same mesh
    without JSON or reflectivity."""
    d = tmp_path_factory.mktemp("gzros")
    t = make_tunnel(Alignment([straight(20.0)]), horseshoe(5.0), edge_length_m=0.3,
                    roughness_rms_m=0.0)
    t.write(d / "t.ply")
    write_ply(d / "bare.ply", t.vertices, t.faces)
    return d


# ------------------------------------------------------------------ topics as gz names
def _text(el, tag, default=None):
    x = el.find(tag)
    return default if x is None or x.text is None else x.text.strip()


def gz_topics(world_sdf):
    """{topic: (gz message type, "pub" or "sub")} of a world, derived from the SDF as
    Gazebo names them: a sensor's explicit <topic> or its scoped default
    (/world/W/model/M/link/L/sensor/S/<kind>), the gpu_lidar's cloud on topic + "/points"
    (gz-sensors GpuLidarSensor); the systems' explicit topics or their documented
    defaults (PosePublisher: /model/M/pose; OdometryPublisher: /model/M/odometry and TF
    on /model/M/pose; DiffDrive: /model/M/cmd_vel, /model/M/odometry, /model/M/tf); the
    server's /clock."""
    root = ET.parse(world_sdf).getroot()
    world = root.find("world")
    w = world.get("name")
    out = {"/clock": ("Clock", "pub"), f"/world/{w}/clock": ("Clock", "pub")}
    for model in world.findall("model"):
        m = model.get("name")
        for link in model.findall("link"):
            for s in link.findall("sensor"):
                kind = s.get("type")
                default = (f"/world/{w}/model/{m}/link/{link.get('name')}/sensor/"
                           f"{s.get('name')}/{'imu' if kind == 'imu' else 'scan'}")
                topic = _text(s, "topic", default)
                if kind == "imu":
                    out[topic] = ("IMU", "pub")
                elif kind == "gpu_lidar":
                    out[topic] = ("LaserScan", "pub")
                    out[topic + "/points"] = ("PointCloudPacked", "pub")
        for p in model.findall("plugin"):
            cls = p.get("name").split("::")[-1]
            if cls == "PosePublisher":
                vec = _text(p, "use_pose_vector_msg", "false") in ("true", "1")
                out[f"/model/{m}/pose"] = ("Pose_V" if vec else "Pose", "pub")
                if _text(p, "static_publisher", "false") in ("true", "1"):
                    out[f"/model/{m}/pose_static"] = ("Pose_V" if vec else "Pose", "pub")
            elif cls == "OdometryPublisher":
                out[_text(p, "odom_topic", f"/model/{m}/odometry")] = ("Odometry", "pub")
                out[_text(p, "tf_topic", f"/model/{m}/pose")] = ("Pose_V", "pub")
            elif cls == "DiffDrive":
                out[_text(p, "topic", f"/model/{m}/cmd_vel")] = ("Twist", "sub")
                out[_text(p, "odom_topic", f"/model/{m}/odometry")] = ("Odometry", "pub")
                out[_text(p, "tf_topic", f"/model/{m}/tf")] = ("Pose_V", "pub")
    return out


def test_topic_derivation_knows_the_points_trap():
    # The cloud of a lidar whose topic ends in /points would be .../points/points: the
    # derivation says so (it is not a rubber stamp), and lidar_sdf refuses that topic.
    xml, _ = lidar_sdf(load_sensor("velodyne_vlp16"), topic="/lidar", indent=0)
    bad = xml.replace("<topic>/lidar</topic>", "<topic>/velodyne/points</topic>")
    doc = (f'<sdf version="1.9"><world name="w"><model name="m"><link name="l">{bad}'
           "</link></model></world></sdf>")
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "w.sdf"
        p.write_text(doc)
        topics = gz_topics(p)
    assert "/velodyne/points/points" in topics and \
        topics["/velodyne/points"] == ("LaserScan", "pub")
    with pytest.raises(GazeboExportError, match="/points/points"):
        lidar_sdf(load_sensor("velodyne_vlp16"), topic="velodyne/points")


# ------------------------------------------------------------------------ the flavours
@pytest.mark.parametrize("fl", ["harmonic", "fortress"])
def test_flavour_validates_and_names_its_own_systems(sdf_check, tunnels, tmp_path, fl):
    exp = EXPECTED[fl]
    info = export_gazebo(tunnels / "t.ply", load_sensor("velodyne_vlp16"), tmp_path / "w",
                         flavour=fl)
    rc, out = _check(sdf_check, tmp_path / "w")
    assert rc == 0 and "error" not in out, out
    text = (tmp_path / "w" / "world.sdf").read_text()
    for other in exp["other"]:
        assert other not in text
    root = ET.fromstring(text)
    plugins = {p.get("filename"): p.get("name") for p in root.iter("plugin")}
    want = {exp["file"].format(stem): exp["cls"].format(cls)
            for stem, cls in SYSTEMS.items()}
    assert plugins == want
    # The IMU system sits in the world, the ground-truth publishers on the robot.
    world = root.find("world")
    assert exp["file"].format("imu") in {p.get("filename") for p in world.findall("plugin")}
    robot = world.find("model[@name='robot']")
    on_robot = {p.get("name") for p in robot.findall("plugin")}
    assert {exp["cls"].format("PosePublisher"), exp["cls"].format("OdometryPublisher")} \
        <= on_robot
    assert robot.find("link/sensor[@type='imu']") is not None
    readme = (tmp_path / "w" / "README.txt").read_text()
    assert f"{exp['env']}=$PWD/models {exp['cmd']} world.sdf" in readme
    assert "parameter_bridge --ros-args -p config_file:=$PWD/bridge.yaml" in readme
    assert info["run"] == f"{exp['env']}=$PWD/models {exp['cmd']} world.sdf"
    assert info["flavour"] == fl


@pytest.mark.parametrize("fl", ["harmonic", "fortress"])
def test_every_bridged_gz_topic_exists_in_the_world(tunnels, tmp_path, fl):
    spec = load_sensor("velodyne_vlp16")
    export_gazebo(tunnels / "t.ply", spec, tmp_path / "w", flavour=fl)
    entries = yaml.safe_load((tmp_path / "w" / "bridge.yaml").read_text())
    topics = gz_topics(tmp_path / "w" / "world.sdf")
    msgs = EXPECTED[fl]["msgs"]
    keys = {"ros_topic_name", "gz_topic_name", "ros_type_name", "gz_type_name",
            "direction"}
    for e in entries:
        assert set(e) == keys
        assert e["gz_topic_name"] in topics, (e, sorted(topics))
        gz_type, way = topics[e["gz_topic_name"]]
        assert e["gz_type_name"] == msgs + gz_type
        assert e["direction"] == ("GZ_TO_ROS" if way == "pub" else "ROS_TO_GZ")
    ros = {e["ros_topic_name"]: (e["ros_type_name"], e["gz_topic_name"]) for e in entries}
    # What a ROS 2 stack needs, on the names a recorded bag of a drive uses.
    assert ros[spec.driver.topic] == ("sensor_msgs/msg/PointCloud2", "/lidar/points")
    assert ros[IMU_TOPIC][0] == "sensor_msgs/msg/Imu"
    assert ros[ODOMETRY_TOPIC][0] == "nav_msgs/msg/Odometry"
    assert ros["/tf"] == ("tf2_msgs/msg/TFMessage", "/model/robot/pose")
    assert ros["/clock"][0] == "rosgraph_msgs/msg/Clock"
    # No two systems publish on one topic with the ground truth (the defaults collide).
    root = ET.parse(tmp_path / "w" / "world.sdf").getroot()
    named = [t.text for p in root.iter("plugin") for tag in ("odom_topic", "tf_topic")
             for t in p.findall(tag)]
    assert len(named) == len(set(named)) and "/model/robot/pose" not in named


def _noise(el):
    return {k: float(el.find(k).text) for k in ("stddev", "bias_stddev",
                                               "dynamic_bias_stddev")}


@pytest.mark.parametrize("imu", [DEFAULT_IMU, ImuModel(
    rate_hz=400.0, gyro_noise_density=3e-4, gyro_random_walk=2e-5,
    accel_noise_density=4e-3, accel_random_walk=5e-4, gyro_bias_sigma=2e-3,
    accel_bias_sigma=0.05)])
def test_imu_noise_is_the_bag_model(tunnels, tmp_path, imu):
    export_gazebo(tunnels / "t.ply", load_sensor("velodyne_vlp16"), tmp_path / "w", imu=imu)
    s = ET.parse(tmp_path / "w" / "world.sdf").getroot().find(
        "world/model/link/sensor[@type='imu']")
    assert float(s.find("update_rate").text) == pytest.approx(imu.rate_hz)
    # Kalibr's discrete white noise: density * sqrt(rate); the random walk's density is
    # the Gauss-Markov driving sigma (gz-sensors GaussianNoiseModel).
    for group, dens, walk, bias in (
            ("angular_velocity", imu.gyro_noise_density, imu.gyro_random_walk,
             imu.gyro_bias_sigma),
            ("linear_acceleration", imu.accel_noise_density, imu.accel_random_walk,
             imu.accel_bias_sigma)):
        for axis in "xyz":
            n = _noise(s.find(f"imu/{group}/{axis}/noise"))
            assert n["stddev"] == pytest.approx(dens * math.sqrt(imu.rate_hz), rel=1e-5)
            assert n["dynamic_bias_stddev"] == pytest.approx(walk, rel=1e-5)
            assert n["bias_stddev"] == pytest.approx(bias, rel=1e-5)


# ---------------------------------------------------------------- retro, origin frame
def _area_weighted(vertices, faces, refl):
    """Reference: Heron's formula per triangle, a plain loop."""
    num = den = 0.0
    for (i, j, k), r in zip(faces, refl):
        a, b, c = (float(np.linalg.norm(vertices[p] - vertices[q]))
                   for p, q in ((i, j), (j, k), (k, i)))
        s = (a + b + c) / 2
        area = math.sqrt(max(s * (s - a) * (s - b) * (s - c), 0.0))
        num += area * r
        den += area
    return num / den


def test_laser_retro_from_the_mesh_reflectivity(tunnels, tmp_path):
    info = export_gazebo(tunnels / "t.ply", load_sensor("velodyne_vlp16"), tmp_path / "w")
    scene, refl = load_mesh(tunnels / "t.ply")
    import trimesh

    m = trimesh.load(str(tunnels / "t.ply"), process=False)
    want = 100.0 * _area_weighted(np.asarray(m.vertices), np.asarray(m.faces), refl)
    assert np.ptp(refl) > 0                 # a mean of different values, not a constant
    model = ET.parse(tmp_path / "w" / "models" / "tunnel" / "model.sdf").getroot()
    for tag in ("visual", "collision"):
        got = float(model.find(f"model/link/{tag}/laser_retro").text)
        assert got == pytest.approx(want, rel=1e-3)
    assert info["laser_retro"] == pytest.approx(want, rel=1e-9)
    # No per-face reflectivity: the default reflectivity (0.5) on the same scale.
    export_gazebo(tunnels / "bare.ply", load_sensor("velodyne_vlp16"), tmp_path / "b",
                  reflectivity=0.3)
    model = ET.parse(tmp_path / "b" / "models" / "tunnel" / "model.sdf").getroot()
    assert float(model.find("model/link/visual/laser_retro").text) == pytest.approx(30.0)


def test_origin_is_a_frame_naming_the_crs(sdf_check, tmp_path):
    pytest.importorskip("pyproj")
    t = make_tunnel(Alignment([straight(12.0)], start_xy=(2_600_000.0, 1_200_000.0),
                              profile=((0.0, 500.0),)),
                    horseshoe(5.0), edge_length_m=0.4, roughness_rms_m=0.0)
    t.with_crs("EPSG:2056").write(tmp_path / "t.ply")
    info = export_gazebo(tmp_path / "t.ply", load_sensor("velodyne_vlp16"), tmp_path / "w",
                         flavour="fortress")
    rc, out = _check(sdf_check, tmp_path / "w")
    assert rc == 0, out                      # libsdformat takes the frame and its element
    frame = ET.parse(tmp_path / "w" / "world.sdf").getroot().find(
        "world/frame[@name='map_origin']")
    pose = np.array(frame.find("pose").text.split(), dtype=float)
    # world = local + origin; the frame is the CRS origin in local coordinates; the
    # origin is the robot's start (base_link) rounded to metres, the map -> odom a
    # drive's bag states for a robot starting there (issue 30).
    start = np.array(info["robot_pose"][:3]) + info["origin"]
    np.testing.assert_allclose(info["origin"], np.round(start), atol=1e-9)
    np.testing.assert_allclose(pose[:3], -np.asarray(info["origin"]), atol=1e-3)
    np.testing.assert_allclose(pose[3:], 0.0)
    assert info["origin"][0] == pytest.approx(2_600_000.0, abs=10.0)
    assert "EPSG:2056" in frame.find(f"{NS}crs").text


# ----------------------------------------------------------------- robot at the route
def test_robot_starts_at_the_route_start_without_json(tunnels, tmp_path):
    info = export_gazebo(tunnels / "bare.ply", load_sensor("velodyne_vlp16"), tmp_path / "w")
    scene, _ = load_mesh(tunnels / "bare.ply")
    route = find_route(scene, height_m=0.5)              # what drive --along auto finds
    x, y, z, yaw = info["robot_pose"]
    start = np.array([x, y, z]) + info["origin"]
    np.testing.assert_allclose(start, route.floor[0], atol=1e-3)
    # Facing along the route: the heading agrees with the route's first metre.
    ahead = route.points[np.searchsorted(route.distance_m, 1.0)] - route.points[0]
    cosang = np.dot([math.cos(yaw), math.sin(yaw)], ahead[:2]) / np.linalg.norm(ahead[:2])
    assert cosang > math.cos(math.radians(10))
    assert info["route"]["length_m"] == pytest.approx(route.length_m, rel=1e-6)
    pose = ET.parse(tmp_path / "w" / "world.sdf").getroot().find(
        "world/model[@name='robot']/pose").text.split()
    np.testing.assert_allclose(np.array(pose[:3], dtype=float), [x, y, z], atol=1e-3)
    # The lamps hang inside the tunnel over the route (local x within its length).
    lamps = [np.array(li.find("pose").text.split()[:3], dtype=float) for li in
             ET.parse(tmp_path / "w" / "world.sdf").getroot().iter("light")]
    import trimesh

    o = np.asarray(info["origin"])
    floor_z = float(trimesh.load(tunnels / "bare.ply", process=False).vertices[:, 2].min())
    assert lamps and all(0.0 <= p[0] + o[0] <= 20.0 and 0.5 < p[2] + o[2] - floor_z < 5.0
                         for p in lamps)


def test_waypoints_choose_the_start_even_with_json(tunnels, tmp_path, capsys):
    wp = tmp_path / "wp.csv"
    wp.write_text("x,y\n15,0\n5,0\n")
    assert main(["gazebo", "--mesh", str(tunnels / "t.ply"), "--sensor", "velodyne_vlp16",
                 "--waypoints", str(wp), "-o", str(tmp_path / "w"),
                 "--flavour", "fortress"]) == 0
    text = capsys.readouterr().out
    assert "start of the route" in text and "ign gazebo" in text
    pose = ET.parse(tmp_path / "w" / "world.sdf").getroot().find(
        "world/model[@name='robot']/pose").text.split()
    # world = local + origin, the origin being where the map_origin frame is not
    frame = ET.parse(tmp_path / "w" / "world.sdf").getroot().find(
        "world/frame[@name='map_origin']/pose").text.split()
    origin = -np.array(frame[:3], dtype=float)
    xy = np.array(pose[:2], dtype=float) + origin[:2]
    np.testing.assert_allclose(xy, [15.0, 0.0], atol=0.05)
    assert abs(abs(float(pose[5])) - math.pi) < math.radians(5)     # facing -x


def test_json_tunnel_keeps_the_axis_start(tunnels, tmp_path):
    info = export_gazebo(tunnels / "t.ply", load_sensor("velodyne_vlp16"), tmp_path / "w",
                         chainage_m=4.0)
    assert info["route"] is None
    x, y, _, yaw = np.array(info["robot_pose"]) + [*info["origin"], 0.0]
    assert (x, y, yaw) == pytest.approx((4.0, 0.0, 0.0), abs=1e-6)


# ------------------------------------------------------------------------- bad input
def _one_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_unknown_flavour_is_an_argparse_error(tunnels, tmp_path, capsys):
    out = tmp_path / "w"
    assert main(["gazebo", "--mesh", str(tunnels / "t.ply"), "--flavour", "classic",
                 "-o", str(out)]) == 2
    assert "invalid choice: 'classic'" in _one_line(capsys)
    assert not out.exists()
    with pytest.raises(GazeboExportError, match="'harmonic' or 'fortress', got 'classic'"):
        export_gazebo(tunnels / "t.ply", load_sensor("velodyne_vlp16"), out,
                      flavour="classic")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("extra, match", [
    (["--chainage", "3"], "Expected a start chainage only for a generated tunnel"),
    (["--waypoints", "WP"], "Expected waypoint 2"),
])
def test_bad_start_is_one_line_exit_2_no_folder(tunnels, tmp_path, capsys, extra, match):
    wp = tmp_path / "wp.csv"
    wp.write_text("1,0\n1,40\n")                     # the second lies outside the tunnel
    argv = ["gazebo", "--mesh", str(tunnels / "bare.ply"), "--sensor", "velodyne_vlp16",
            "-o", str(tmp_path / "w")] + [str(wp) if a == "WP" else a for a in extra]
    assert main(argv) == 2
    line = _one_line(capsys)
    assert line.startswith("tunnelsim: error:") and match in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["wp.csv"]
