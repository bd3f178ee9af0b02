"""ROS 2 bags: read back with rosbags (topics, counts, driver field layouts, stamps), one
sweep against the LAZ of the same run, the rings and the Ouster SDK's column formula,
the ground truth (tf, odometry) against the trajectory and the LAZ world points, the
IMU against the trajectory's derivatives, KISS-ICP's own rosbag loader, bad input."""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import (
    Mount,
    PointFileError,
    SensorSpecError,
    Trajectory,
    load_sensor,
    simulate_drive,
    simulate_station,
)
from sensors.imu import DEFAULT_IMU, STANDARD_GRAVITY, ImuModel
from sensors.bag import RosbagStream
from sensors.patterns import SpinningScan
from sensors.spec import SPEC_DIR
from sensors.writers import open_writer

rosbags = pytest.importorskip("rosbags", reason="rosbags is in the test extra")
from rosbags.highlevel import AnyReader  # noqa: E402

T0, DURATION = 100.0, 0.55            # 5 whole sweeps at 10 Hz and a partial one
SENSORS = ["velodyne_vlp16", "ouster_os1_64", "robosense_airy"]
MOUNTS = {"velodyne_vlp16": Mount.from_degrees((0.2, 0.0, 0.4), yaw_deg=3.0),
          "ouster_os1_64": Mount((0.1, 0.05, 0.35)),
          "robosense_airy": Mount.pointing_down((0.3, 0.0, 0.5))}
#: The cloud topic and frame each driver publishes by default.
DRIVER = {"velodyne_vlp16": ("/velodyne_points", "velodyne"),
          "ouster_os1_64": ("/ouster/points", "os_sensor"),
          "robosense_airy": ("/rslidar_points", "rslidar")}


@pytest.fixture(scope="module")
def scene():
    v, f = tunnel_tube(20_000, length_m=60.0, seed=1)
    return Scene(v, f)


@pytest.fixture(scope="module")
def traj():
    return Trajectory.along_polyline([[5.0, 0.0, 1.4], [50.0, 0.5, 1.4]], 2.0, rate_hz=100,
                                     start_time=T0)


def _run(scene, traj, name, **kw):
    return simulate_drive(scene, name, traj, MOUNTS[name], seed=3, t_end=T0 + DURATION,
                          **kw)


def _write(run, traj, path, **kw):
    """As ``Run.write`` streams a run (plus the trajectory and window for the bag)."""
    with open_writer(path, sensor=run.sensor, seed=run.seed, mount=run.mount,
                     trajectory=traj, span_s=(run.t0, run.t0 + run.duration_s), **kw) as w:
        for chunk in run:
            w.write_points(chunk)
    return w


@pytest.fixture(scope="module")
def bags(scene, traj, tmp_path_factory):
    """Per sensor: (bag path, writer, all points of the run, LAZ path)."""
    out = {}
    d = tmp_path_factory.mktemp("bags")
    for name in SENSORS:
        run = _run(scene, traj, name)
        w = _write(run, traj, d / f"{name}.mcap")
        laz = d / f"{name}.laz"
        _write(run, traj, laz, fields="full")
        out[name] = (d / f"{name}.mcap", w, np.concatenate(list(run)), laz)
    return out


@functools.lru_cache(maxsize=32)
def _read_cached(path, topic):
    with AnyReader([Path(path)]) as r:
        conns = [c for c in r.connections if topic is None or c.topic == topic]
        return [(c.topic, t, r.deserialize(raw, c.msgtype))
                for c, t, raw in r.messages(connections=conns)]


def _read(path, topic=None):
    """[(topic, log time ns, message)] in log-time order (each bag is read once)."""
    return _read_cached(str(path), topic)


@functools.lru_cache(maxsize=8)
def _laz(path):
    return laspy.read(path)


def _stamp(msg):
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def _grid(msg):
    """The cloud's records (height x width,), row-major, with the dtype its own fields
    describe."""
    types = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
    dt = np.dtype({"names": [f.name for f in msg.fields],
                   "formats": ["<" + types[f.datatype] for f in msg.fields],
                   "offsets": [f.offset for f in msg.fields], "itemsize": msg.point_step})
    out = np.frombuffer(np.asarray(msg.data, dtype=np.uint8).tobytes(), dtype=dt)
    assert len(out) == msg.height * msg.width
    return out


def _points(msg):
    """The cloud's returns: an unorganised cloud as it is; an organised one (rows =
    rings = the OS1's channels) column by column, without the cells of no return
    (range 0), i.e. in the simulation's pulse order."""
    g = _grid(msg)
    if msg.height == 1:
        return g
    g = g.reshape(msg.height, msg.width).T.ravel()
    return g[g["range"] > 0]


# ---------------------------------------------------------------- topics and layouts
@pytest.mark.parametrize("name", SENSORS)
def test_topics_counts_and_types(bags, name):
    path, w, pts, _ = bags[name]
    topic, _frame = DRIVER[name]
    with AnyReader([path]) as r:
        got = {t: (i.msgtype, i.msgcount) for t, i in r.topics.items()}
    n_whole = int(np.floor(DURATION * 10.0 + 1e-9))
    assert got == {topic: ("sensor_msgs/msg/PointCloud2", n_whole),
                   "/tf_static": ("tf2_msgs/msg/TFMessage", 1),
                   "/tf": ("tf2_msgs/msg/TFMessage", 56),            # 0 .. 0.55 s at 100 Hz
                   "/odometry/ground_truth": ("nav_msgs/msg/Odometry", 56),
                   "/imu/data_raw": ("sensor_msgs/msg/Imu", 111)}    # at 200 Hz
    # the partial sixth sweep is dropped, and counted
    assert w._w.dropped_points == np.count_nonzero(pts["frame"] >= n_whole) > 0


def _packed(fields):
    """Offsets of fields laid out one after another (sensor_msgs addPointField)."""
    size = {"f4": 4, "u2": 2, "f8": 8}
    out, off = [], 0
    for n, t in fields:
        out.append((n, off, t))
        off += size[t]
    return out, off


#: The drivers' layouts, derived here from their definitions: velodyne_pointcloud and
#: rslidar_sdk pack the fields; ouster_ros::Point is a C struct (PCL_ADD_POINT4D: x, y,
#: z and a pad float; each member aligned to its size; EIGEN_ALIGN16: size rounded up
#: to 16 bytes).
VELODYNE = _packed([("x", "f4"), ("y", "f4"), ("z", "f4"), ("intensity", "f4"),
                    ("ring", "u2"), ("time", "f4")])
ROBOSENSE = _packed([("x", "f4"), ("y", "f4"), ("z", "f4"), ("intensity", "f4"),
                     ("ring", "u2"), ("timestamp", "f8")])


def _c_struct(members):
    out, off = [], 0
    for n, t, size in members:
        off = -(-off // size) * size
        if n != "pad":
            out.append((n, off, t))
        off += size
    return out, -(-off // 16) * 16


OUSTER = _c_struct([("x", "f4", 4), ("y", "f4", 4), ("z", "f4", 4), ("pad", "f4", 4),
                    ("intensity", "f4", 4), ("t", "u4", 4), ("reflectivity", "u2", 2),
                    ("ring", "u2", 2), ("ambient", "u2", 2), ("range", "u4", 4)])
LAYOUT = {"velodyne_vlp16": VELODYNE, "ouster_os1_64": OUSTER, "robosense_airy": ROBOSENSE}
ROS_TYPE = {"u2": 4, "u4": 6, "f4": 7, "f8": 8}


@pytest.mark.parametrize("name", SENSORS)
def test_fields_offsets_and_datatypes_follow_the_driver(bags, name):
    (fields, step) = LAYOUT[name]
    assert {"velodyne_vlp16": 22, "ouster_os1_64": 48, "robosense_airy": 26}[name] == step
    topic, frame = DRIVER[name]
    for _t, _log, msg in _read(bags[name][0], topic):
        assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == \
            [(n, o, ROS_TYPE[t], 1) for n, o, t in fields]
        organised = name == "ouster_os1_64"       # ouster-ros organises its clouds
        assert (msg.height, msg.width) == (64, 1024) if organised else msg.height == 1
        assert msg.point_step == step and not msg.is_bigendian
        assert msg.row_step == step * msg.width
        assert msg.row_step * msg.height == len(msg.data)
        empty = (_grid(msg)["range"] == 0).sum() if organised else 0
        assert msg.header.frame_id == frame and msg.is_dense == (empty == 0)


@pytest.mark.parametrize("name", SENSORS)
def test_stamps_are_sweep_starts_and_log_times_never_decrease(bags, name):
    msgs = _read(bags[name][0])
    logs = [t for _topic, t, _m in msgs]
    assert logs == sorted(logs)
    clouds = [(t, m) for topic, t, m in msgs if topic == DRIVER[name][0]]
    for k, (log, m) in enumerate(clouds):
        ns = m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
        assert ns == round((T0 + k * 0.1) * 1e9)           # sweep start
        assert log == round((T0 + (k + 1) * 0.1) * 1e9)    # published at its end
    for topic in ("/tf", "/odometry/ground_truth", "/imu/data_raw"):
        s = [_stamp(m.transforms[0]) if topic == "/tf" else _stamp(m)
             for tp, _t, m in msgs if tp == topic]
        assert np.all(np.diff(s) > 0) and s[0] == pytest.approx(T0)


# ---------------------------------------------------------------- points and rings
@pytest.mark.parametrize("name", SENSORS)
def test_a_sweep_equals_the_laz_sensor_points(bags, name):
    path, _w, _pts, laz_path = bags[name]
    las = _laz(laz_path)
    k = 2
    sel = np.asarray(las["frame"]) == k
    cloud = _points(_read(path, DRIVER[name][0])[k][2])
    assert len(cloud) == sel.sum() > 1000
    for a, b in (("x", "sensor_x"), ("y", "sensor_y"), ("z", "sensor_z")):
        np.testing.assert_array_equal(cloud[a], np.asarray(las[b])[sel].astype(np.float32))
    stamp = T0 + k * 0.1
    t = np.asarray(las.gps_time)[sel]
    i_las = np.asarray(las.intensity)[sel] / 65535        # LAS: round(i * 65535)
    if name != "ouster_os1_64":                           # the drivers' scale 255
        np.testing.assert_allclose(cloud["intensity"], i_las * 255, atol=255 / 65535)
    else:
        # signal photons = S P / P_min = S 10^(i log10(P_sat / P_min)); the LAS
        # intensity's quantum 1/65535 gives a relative error of ln(10) span / 65535
        phys = load_sensor(name).physics
        span = np.log10(phys.saturation_power / phys.threshold_power)
        np.testing.assert_allclose(cloud["intensity"], np.minimum(
            10.0 * 10 ** (i_las * span), 65535), rtol=np.log(10) * span / 65535 * 1.01)
    if name == "velodyne_vlp16":
        np.testing.assert_allclose(cloud["time"], t - stamp, atol=1e-7)
    elif name == "ouster_os1_64":
        np.testing.assert_array_equal(cloud["t"], np.round((t - stamp) * 1e9))
        np.testing.assert_allclose(cloud["range"], np.asarray(las["range"])[sel] * 1e3,
                                   atol=0.5)
        assert not cloud["ambient"].any()
    else:
        np.testing.assert_array_equal(cloud["timestamp"], t)


@pytest.mark.parametrize("name, lowest_first", [("velodyne_vlp16", True),
                                                ("ouster_os1_64", False),
                                                ("robosense_airy", True)])
def test_rings_follow_the_drivers_elevation_order(bags, name, lowest_first):
    """Ring r holds one beam; its elevation (LAZ extra bytes) rises (falls) with r."""
    path, _w, _pts, laz_path = bags[name]
    las = _laz(laz_path)
    sel = np.asarray(las["frame"]) == 1
    el = np.rad2deg(np.asarray(las["elevation"])[sel].astype(np.float64))
    ring = _points(_read(path, DRIVER[name][0])[1][2])["ring"].astype(int)
    per_ring = np.array([np.unique(el[ring == r]).item() for r in np.unique(ring)])
    assert np.all(np.diff(per_ring) > 0) == lowest_first
    assert np.all(np.diff(per_ring) < 0) != lowest_first
    if name == "velodyne_vlp16":       # the example: ring 0 -15 deg, ring 15 +15
        assert np.unique(ring).tolist() == list(range(16))
        np.testing.assert_allclose(per_ring, np.arange(-15, 16, 2), atol=1e-5)
        ch = np.asarray(las["channel"])[sel]            # the firing order stays
        for c, r in ((0, 0), (1, 8), (2, 1)):           # -15, +1, -13 deg
            assert np.all(ring[ch == c] == r) and np.any(ch == c)


def test_ouster_columns_follow_the_sdk_formula():
    """ouster-sdk make_xyz_lut: column v, row u in the lidar frame: encoder
    2 pi - v 2 pi / W, azimuth -beam_azimuth (0 here), altitude beam_altitude[u];
    lidar_to_sensor_transform (design value) rotates by diag(-1, -1, 1)."""
    spec = load_sensor("ouster_os1_64")
    scan = SpinningScan(spec, 0.1)
    c = next(iter(scan.chunks(chunk_pulses=64 * 1024)))
    W = 1024
    v = c.column.astype(float)
    phi = spec.pattern.elevations_rad[c.channel]           # rows top down: ring = row
    enc = 2 * np.pi - v * 2 * np.pi / W
    d_lidar = np.stack([np.cos(enc) * np.cos(phi), np.sin(enc) * np.cos(phi),
                        np.sin(phi)], 1)
    d_sensor = d_lidar @ np.diag([-1.0, -1.0, 1.0]).T
    assert len(v) == 64 * W and v.max() == W - 1
    np.testing.assert_allclose(c.direction, d_sensor, atol=1e-12)
    assert np.all(np.diff(np.rad2deg(spec.pattern.elevations_rad)) < 0)   # row 0 on top


# ---------------------------------------------------------------- ground truth
def _static(msgs):
    m = next(m for t, _l, m in msgs if t == "/tf_static")
    return {(tf.header.frame_id, tf.child_frame_id): tf.transform for tf in m.transforms}


def _xyz(v):
    return np.array([v.x, v.y, v.z])


def _quat(q):
    return np.array([q.x, q.y, q.z, q.w])


@pytest.mark.parametrize("name", SENSORS)
def test_tf_and_odometry_are_the_true_trajectory(bags, traj, name):
    msgs = _read(bags[name][0])
    static = _static(msgs)
    np.testing.assert_array_equal(_xyz(static["map", "odom"].translation), traj.origin)
    mount_tf = static["base_link", DRIVER[name][1]]
    np.testing.assert_allclose(_xyz(mount_tf.translation), MOUNTS[name].lever_arm_m)
    assert (Rotation.from_quat(_quat(mount_tf.rotation)) *
            MOUNTS[name].boresight.inv()).magnitude() < 1e-12
    odo = [m for t, _l, m in msgs if t == "/odometry/ground_truth"]
    t = np.array([_stamp(m) for m in odo])
    pos, rot = traj.interpolate(t)
    p = np.array([_xyz(m.pose.pose.position) for m in odo]) + traj.origin
    np.testing.assert_allclose(p, pos, atol=1e-9)
    q = Rotation.from_quat([_quat(m.pose.pose.orientation) for m in odo])
    assert np.all((q * rot.inv()).magnitude() < 1e-9)
    # 2 m/s along the polyline, expressed in base_link
    v = np.array([_xyz(m.twist.twist.linear) for m in odo])
    np.testing.assert_allclose(v, np.tile([2.0, 0.0, 0.0], (len(v), 1)), atol=1e-9)


@pytest.mark.parametrize("name", SENSORS)
def test_world_points_follow_from_the_bag_alone(bags, name):
    """map <- odom <- base_link (tf, interpolated at each point's time) <- lidar
    (tf_static) applied to a cloud's points gives the LAZ world points (0.1 mm)."""
    path, _w, _pts, laz_path = bags[name]
    msgs = _read(path)
    static = _static(msgs)
    tfs = [m.transforms[0] for tp, _l, m in msgs if tp == "/tf"]
    tt = np.array([_stamp(tf) for tf in tfs])
    tp = np.array([_xyz(tf.transform.translation) for tf in tfs])
    slerp = Slerp(tt, Rotation.from_quat([_quat(tf.transform.rotation) for tf in tfs]))
    k = 3
    cloud = _points([m for tpc, _l, m in msgs if tpc == DRIVER[name][0]][k])
    stamp = T0 + k * 0.1
    t = {"velodyne_vlp16": lambda c: stamp + c["time"].astype(np.float64),
         "ouster_os1_64": lambda c: stamp + c["t"] * 1e-9,
         "robosense_airy": lambda c: c["timestamp"]}[name](cloud)
    mount = static["base_link", DRIVER[name][1]]
    s = np.stack([cloud["x"], cloud["y"], cloud["z"]], 1).astype(np.float64)
    body = Rotation.from_quat(_quat(mount.rotation)).apply(s) + _xyz(mount.translation)
    shift = np.stack([np.interp(t, tt, tp[:, j]) for j in range(3)], 1)
    odom = slerp(t).apply(body) + shift
    world = odom + _xyz(static["map", "odom"].translation)
    las = _laz(laz_path)
    sel = np.asarray(las["frame"]) == k
    ref = np.stack([las.x, las.y, las.z], 1)[sel]
    # float32 sensor coordinates (< 5 um at 10 m) and the LAS 0.1 mm grid
    assert np.abs(world - ref).max() < 1e-4


# ---------------------------------------------------------------- IMU
def _arc(radius=8.0, speed=2.0, seconds=6.0, rate=100.0, climb=0.0):
    """A level circular arc at constant speed, heading along it: yaw rate w = v / R,
    body acceleration (0, v^2 / R, 0)."""
    t = np.arange(0.0, seconds + 1e-9, 1.0 / rate) + 10.0
    a = speed / radius * (t - 10.0)
    pos = np.stack([radius * np.sin(a), radius * (1 - np.cos(a)), climb * (t - 10.0)], 1)
    return Trajectory(t, pos, Rotation.from_euler("z", a[:, None]))


def _imu_bag(tmp_path, traj, imu, seed=0, name="imu.mcap"):
    spec = load_sensor("velodyne_vlp16")
    span = (traj.start_s, traj.end_s)
    w = RosbagStream(tmp_path / name, spec, single_file=True, seed=seed, trajectory=traj,
                     span_s=span, imu=imu)
    w.close()
    msgs = _read(tmp_path / name, "/imu/data_raw")
    t = np.array([_stamp(m) for _t, _l, m in msgs])
    g = np.array([_xyz(m.angular_velocity) for _t, _l, m in msgs])
    a = np.array([_xyz(m.linear_acceleration) for _t, _l, m in msgs])
    return t, g, a, [m for _t, _l, m in msgs]


def test_noiseless_imu_equals_the_analytic_derivatives(tmp_path):
    R, v = 8.0, 2.0
    quiet = ImuModel(gyro_noise_density=0, gyro_random_walk=0, accel_noise_density=0,
                     accel_random_walk=0, gyro_bias_sigma=0, accel_bias_sigma=0)
    t, g, a, msgs = _imu_bag(tmp_path, _arc(R, v), quiet)
    assert len(t) == 6 * 200 + 1
    inner = (t > 10.02) & (t < 15.98)
    np.testing.assert_allclose(g[inner], np.tile([0, 0, v / R], (inner.sum(), 1)),
                               atol=1e-9)
    # centripetal, to the left (+y), and gravity's reaction (+z), in base_link;
    # the second difference of a sampled circle is exact to (w h)^2 / 12
    np.testing.assert_allclose(a[inner], np.tile([0, v * v / R, STANDARD_GRAVITY],
                                                 (inner.sum(), 1)), rtol=1e-5, atol=1e-9)
    m = msgs[0]
    assert m.header.frame_id == "base_link" and m.orientation_covariance[0] == -1.0


def test_imu_means_match_the_trajectory_within_the_modelled_noise(tmp_path):
    """Over 6 s at 200 Hz, the mean of gyro z and accel y minus the truth is the
    turn-on bias plus the random walk's mean plus white noise / sqrt(n); 4 sigma of
    that sum bounds it. The spread of the first differences is sqrt(2) x the white
    sigma (the random walk adds < 1 %), within 10 % (n = 1200, rel. sigma 2 %)."""
    R, v = 8.0, 2.0
    imu = DEFAULT_IMU
    t, g, a, _ = _imu_bag(tmp_path, _arc(R, v), imu, seed=11)
    inner = (t > 10.02) & (t < 15.98)
    n = inner.sum()
    sg, sa, sbg, sba = imu.sample_sigmas()
    rw = np.sqrt(n / 3)                  # sd of the mean of a random walk of n steps
    for res, white, step, turn_on in ((g[inner, 2] - v / R, sg, sbg, imu.gyro_bias_sigma),
                                      (a[inner, 1] - v * v / R, sa, sba,
                                       imu.accel_bias_sigma)):
        bound = 4 * np.sqrt(turn_on ** 2 + (step * rw) ** 2 + white ** 2 / n)
        assert abs(res.mean()) < bound
        assert np.std(np.diff(res)) == pytest.approx(np.sqrt(2) * white, rel=0.1)
    # seeded: the same seed gives the same samples, another seed others
    t2, g2, _a2, _ = _imu_bag(tmp_path, _arc(R, v), imu, seed=11, name="again.mcap")
    np.testing.assert_array_equal(g2, g)
    _t3, g3, _a3, _ = _imu_bag(tmp_path, _arc(R, v), imu, seed=12, name="other.mcap")
    assert not np.allclose(g3, g)


def test_bag_does_not_depend_on_the_chunk_size(scene, traj, tmp_path):
    name = "velodyne_vlp16"
    a = _write(_run(scene, traj, name, chunk_pulses=9_000), traj, tmp_path / "a.mcap")
    b = _write(_run(scene, traj, name, chunk_pulses=400_000), traj, tmp_path / "b.mcap")
    assert a._w.messages == b._w.messages
    for (ta, la, ma), (tb, lb, mb) in zip(_read(a.path), _read(b.path), strict=True):
        assert (ta, la) == (tb, lb)
        if ta == DRIVER[name][0]:
            np.testing.assert_array_equal(_points(ma), _points(mb))
        elif ta == "/imu/data_raw":
            assert _xyz(ma.angular_velocity).tolist() == _xyz(mb.angular_velocity).tolist()


# ---------------------------------------------------------------- a real client
@pytest.mark.parametrize("name", SENSORS)
def test_kiss_icp_reads_every_sweep_with_its_point_times(bags, name):
    pytest.importorskip("kiss_icp", reason="KISS-ICP is in the test extra")
    from kiss_icp.datasets.rosbag import RosbagDataset

    path = bags[name][0]
    topic = DRIVER[name][0]
    clouds = [m for _t, _l, m in _read(path, topic)]
    ds = RosbagDataset(path, topic=topic)
    assert len(ds) == len(clouds) == 5
    field = {"velodyne_vlp16": "time", "ouster_os1_64": "t",
             "robosense_airy": "timestamp"}[name]
    for i, msg in enumerate(clouds):
        xyz, times = ds[i]
        ref = _grid(msg)           # an organised cloud's every cell (zeros included)
        assert len(xyz) == len(times) == len(ref) > 1000
        np.testing.assert_array_equal(xyz[:, 0], ref["x"].astype(np.float64))
        np.testing.assert_array_equal(times, ref[field].astype(np.float64))
        assert np.ptp(times) > 0                     # per-point times, not one stamp


def test_a_bag_folder_as_ros2_bag_record_makes_it(scene, traj, tmp_path):
    pytest.importorskip("kiss_icp", reason="KISS-ICP is in the test extra")
    from kiss_icp.datasets.rosbag import RosbagDataset

    run = _run(scene, traj, "robosense_airy")
    _write(run, traj, tmp_path / "drive_bag")
    d = tmp_path / "drive_bag"
    assert sorted(p.name for p in d.iterdir()) == ["drive_bag.mcap", "metadata.yaml"]
    assert [p.name for p in tmp_path.iterdir()] == ["drive_bag"]      # no temporaries
    assert len(RosbagDataset(d, topic="/rslidar_points")) == 5


def test_run_write_streams_a_bag(scene, traj, tmp_path):
    """Through ``Run.write`` (whatever it passes on: clouds at least)."""
    run = _run(scene, traj, "velodyne_vlp16")
    stats = run.write(tmp_path / "d.mcap")
    with AnyReader([tmp_path / "d.mcap"]) as r:
        assert r.topics["/velodyne_points"].msgcount in (5, 6)
    assert stats["points"] == len(np.concatenate(list(run)))


# ---------------------------------------------------------------- bad input
def test_bad_input_is_refused_and_leaves_nothing(scene, traj, tmp_path, monkeypatch):
    run = _run(scene, traj, "velodyne_vlp16")
    with pytest.raises(PointFileError, match="output format.*'xyz'"):
        open_writer(tmp_path / "d.xyz", sensor="velodyne_vlp16")
    station = simulate_station(scene, "zf_imager_5016", [30.0, 0.0, 1.4],
                               resolution="preview")
    with pytest.raises(PointFileError, match="moving platform.*TLS station"):
        station.write(tmp_path / "s.mcap")
    with pytest.raises(PointFileError, match="spinning lidar or a profiler.*TLS"):
        open_writer(tmp_path / "s.mcap", sensor="zf_imager_5016")
    (tmp_path / "taken").mkdir()
    with pytest.raises(PointFileError, match="new bag folder"):
        open_writer(tmp_path / "taken", sensor="velodyne_vlp16")
    with pytest.raises(SensorSpecError, match="sensor name"):
        open_writer(tmp_path / "u.mcap", sensor="my_scanner")
    with pytest.raises(RuntimeError, match="crash"), \
            open_writer(tmp_path / "f.mcap", sensor=run.sensor, trajectory=traj,
                        span_s=(T0, T0 + DURATION)) as w:
        w.write_points(next(iter(run)))
        raise RuntimeError("simulated crash")
    early = Trajectory.along_polyline([[5.0, 0.0, 1.4], [50.0, 0.0, 1.4]], 2.0,
                                      start_time=-1.0)
    with pytest.raises(PointFileError, match="times >= 0"):
        _write(simulate_drive(scene, "velodyne_vlp16", early, t_end=-0.5), early,
               tmp_path / "neg.mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"]
    monkeypatch.setitem(sys.modules, "rosbags.rosbag2", None)
    with pytest.raises(PointFileError, match=r"rosbags.*pip install"):
        open_writer(tmp_path / "m.mcap", sensor="velodyne_vlp16")


def test_out_of_order_points_are_refused(tmp_path):
    from sensors.io.fields import POINT_DTYPE

    pts = np.zeros(3, dtype=POINT_DTYPE)
    pts["frame"] = [1, 1, 0]
    with pytest.raises(PointFileError, match="time order"), \
            open_writer(tmp_path / "o.mcap", sensor="velodyne_vlp16") as w:
        w.write_points(pts)
    assert not list(tmp_path.iterdir())


def test_driver_tables_are_strict(tmp_path):
    text = (SPEC_DIR / "velodyne_vlp16.toml").read_text()
    p = tmp_path / "mine.toml"
    for old, new, match in [
            ('ring_order = "elevation_ascending"', 'ring_order = "sideways"', "ring_order"),
            ('point_layout = "velodyne"', 'point_layout = "hesai"', "point_layout"),
            ('frame_id = "velodyne"', 'frame_id = "/velodyne"', "frame_id"),
            ('intensity_max = 255.0', 'intensity_max = 0.0', "intensity_max")]:
        p.write_text(text.replace(old, new))
        with pytest.raises(SensorSpecError, match=rf"driver\.{match}.*mine\.toml"):
            load_sensor(p)
    # no [driver] table: the generic layout (velodyne fields, ring = channel)
    p.write_text(text[:text.index("[driver]")])
    assert load_sensor(p).driver is None


# ---------------------------------------------------------------- properties
@given(st.lists(st.integers(-8900, 8900), min_size=1, max_size=40, unique=True),
       st.sampled_from(["elevation_ascending", "elevation_descending", "channel"]))
def test_rings_are_the_elevation_ranks(centidegrees, order):
    """Distinct elevations: a permutation of 0..n-1 that sorts the beams by elevation
    (reference: argsort of argsort); a repeated elevation shares its ring."""
    from dataclasses import replace

    from sensors.pointcloud2 import GENERIC_DRIVER

    el = np.deg2rad(np.array(centidegrees) / 100.0)
    driver = replace(GENERIC_DRIVER, ring_order=order)
    rings = driver.rings(el)
    assert sorted(rings.tolist()) == list(range(len(el)))
    if order == "channel":
        assert rings.tolist() == list(range(len(el)))
    else:
        key = el if order == "elevation_ascending" else -el
        np.testing.assert_array_equal(rings, np.argsort(np.argsort(key)))
        twin = driver.rings(np.append(el, el[0]))
        assert twin[-1] == twin[0] == rings[0]


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 300), st.integers(0, 2 ** 32),
       st.sampled_from(["velodyne_vlp16", "ouster_os1_64", "robosense_airy"]))
def test_cloud_bytes_decode_with_the_drivers_layout(n, seed, name):
    """Random records through cloud_points, to bytes, decoded with the layouts derived
    in this file from the drivers' definitions: every field where it belongs."""
    from sensors.pointcloud2 import LAYOUTS, cloud_points
    from sensors.io.fields import POINT_DTYPE

    spec = load_sensor(name)
    g = np.random.default_rng(seed)
    rec = np.zeros(n, dtype=POINT_DTYPE)
    for f in ("sx", "sy", "sz"):
        rec[f] = g.uniform(-100, 100, n)
    rec["range"] = g.uniform(0.1, 100, n)
    rec["intensity"] = g.uniform(0, 1, n)
    rec["channel"] = g.integers(0, spec.channels, n)
    stamp = 1_700_000_000.0
    rec["time"] = stamp + g.uniform(0, 0.1, n)
    rings = spec.driver.rings(spec.pattern.elevations_rad)
    layout = LAYOUTS[spec.driver.point_layout]
    raw = cloud_points(layout, rec, stamp, rings, 255.0, physics=spec.physics,
                       signal_photons_at_threshold=10.0).view(np.uint8).tobytes()
    fields, step = LAYOUT[name]
    got = np.frombuffer(raw, dtype=np.dtype({"names": [f[0] for f in fields],
                                             "formats": ["<" + f[2] for f in fields],
                                             "offsets": [f[1] for f in fields],
                                             "itemsize": step}))
    for a, b in (("x", "sx"), ("y", "sy"), ("z", "sz")):
        np.testing.assert_array_equal(got[a], rec[b].astype(np.float32))
    np.testing.assert_array_equal(got["ring"], rings[rec["channel"]])
    if name == "ouster_os1_64":
        # signal photons: 10 at P_min, proportional to P = P_min (P_sat/P_min)^i;
        # calibrated reflectivity 100 P R^2, within a byte
        ph = spec.physics
        p = ph.threshold_power * (ph.saturation_power / ph.threshold_power) ** \
            rec["intensity"].astype(np.float64)
        np.testing.assert_allclose(got["intensity"], np.minimum(
            10.0 * p / ph.threshold_power, 65535.0), rtol=1e-6)   # a 16-bit SIGNAL
        refl = np.clip(100 * p * rec["range"] ** 2, 0, 255)
        assert np.all(np.abs(got["reflectivity"] - refl) <= 0.5 + 1e-6 * refl)
        assert not got["ambient"].any()
        assert np.all(np.abs(got["t"] * 1e-9 - (rec["time"] - stamp)) <= 1e-9)
        assert np.all(np.abs(got["range"] - rec["range"] * 1e3) <= 0.5)
    else:
        np.testing.assert_allclose(got["intensity"], rec["intensity"] * 255.0, rtol=1e-6)
    if name == "robosense_airy":
        np.testing.assert_array_equal(got["timestamp"], rec["time"])
    elif name == "velodyne_vlp16":
        np.testing.assert_allclose(got["time"], rec["time"] - stamp, atol=1e-7)
