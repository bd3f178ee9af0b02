"""Bags of dual-return drives in each driver's layout (issue 34), read with rosbags.

ouster-ros publishes return 2 on a topic of its own (src/os_ros.cpp topic_for_return:
"points" + "2") in the same organised layout; velodyne_pointcloud puts both returns of a
firing into the one /velodyne_points cloud, consecutive, in its unchanged 22-byte layout
(velodyne_pointcloud/src/lib/rawdata.cpp). References: the simulation's own records
(return_number, sensor-frame points), the C struct offsets of ouster_ros::Point derived
as tests/sensors/test_ouster_organised.py derives them, and, for the default path, the
bytes of the single-return drive's messages."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import Trajectory, load_sensor, simulate_drive
from sensors.io.fields import RETURN_POINT_DTYPE
from sensors.physics import Settings
from sensors.pointcloud2 import returns_in_one_cloud
from sensors.writers import open_writer

pytest.importorskip("rosbags", reason="rosbags is in the test extra")
from rosbags.highlevel import AnyReader  # noqa: E402

from tests.sensors.test_ouster_organised import (OUSTER, ROS_TYPE, STEP,  # noqa: E402
                                                 _grid, _rows)

T0 = 50.0
# Dust in the air: a particle echo in front of the lining gives pulses two returns.
DUSTY = Settings(returns="dual", particle_rate_per_m=0.05)
VELODYNE = [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 12, "f4"),
            ("ring", 16, "u2"), ("time", 18, "f4")]


@pytest.fixture(scope="module")
def scene():
    v, f = tunnel_tube(6_000, length_m=20.0, seed=5)
    return Scene(v, f)


@pytest.fixture(scope="module")
def traj():
    return Trajectory.along_polyline([[4.0, 0.0, 1.4], [10.0, 0.0, 1.4]], 1.0, rate_hz=50,
                                     start_time=T0)


def _write(run, traj, path):
    with open_writer(path, sensor=run.sensor, seed=run.seed, mount=run.mount,
                     trajectory=traj, span_s=(run.t0, run.t0 + run.duration_s)) as w:
        for chunk in run:
            w.write_points(chunk)


def _clouds(path):
    """topic -> its PointCloud2 messages (deserialised) and raw CDR bytes, in order;
    and every topic's message count."""
    out: dict[str, list] = {}
    with AnyReader([Path(path)]) as r:
        counts = {c.topic: c.msgcount for c in r.connections}
        conns = [c for c in r.connections if c.msgtype == "sensor_msgs/msg/PointCloud2"]
        for c, _t, raw in r.messages(connections=conns):
            out.setdefault(c.topic, []).append((r.deserialize(raw, c.msgtype), bytes(raw)))
    return out, counts


def _dtype(fields, step):
    return np.dtype({"names": [n for n, _o, _t in fields],
                     "formats": ["<" + t for _n, _o, t in fields],
                     "offsets": [o for _n, o, _t in fields], "itemsize": step})


@pytest.fixture(scope="module")
def os1(scene, traj, tmp_path_factory):
    run = simulate_drive(scene, "ouster_os1_64", traj, seed=3, t_end=T0 + 0.2,
                         settings=DUSTY)
    path = tmp_path_factory.mktemp("os1") / "os1.mcap"
    _write(run, traj, path)
    return run, np.concatenate(list(run)), _clouds(path)


def test_the_ouster_bag_has_a_topic_per_return(os1):
    run, pts, (clouds, counts) = os1
    assert pts.dtype == RETURN_POINT_DTYPE
    assert set(clouds) == {"/ouster/points", "/ouster/points2"}
    assert counts["/ouster/points"] == counts["/ouster/points2"] == 2
    rows = _rows(run.sensor)
    T = run.sensor.pattern.column_period_s
    n2 = 0
    for topic, want in (("/ouster/points", 1), ("/ouster/points2", 2)):
        for k, (msg, _raw) in enumerate(clouds[topic]):
            assert (msg.height, msg.width) == (64, 1024) and not msg.is_dense
            assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == \
                [(n, o, ROS_TYPE[t], 1) for n, o, t in OUSTER]
            assert msg.point_step == STEP == 48 and msg.row_step == 48 * 1024
            g = _grid(msg)
            sweep = pts[(pts["frame"] == k) & (pts["return_number"] == want)]
            r, c = rows[sweep["channel"]], sweep["column"]
            hit = np.zeros((64, 1024), dtype=bool)
            hit[r, c] = True
            assert hit.sum() == len(sweep) > 0
            # the cells of this return's pulses hold its point; the others are empty
            empty = g[~hit]
            for f in ("x", "y", "z", "intensity", "reflectivity", "range"):
                assert not empty[f].any(), (topic, f)
            col = np.tile(np.arange(1024), (64, 1))
            np.testing.assert_array_equal(g["t"][~hit], np.round(col[~hit] * T * 1e9))
            np.testing.assert_array_equal(g["ring"], np.repeat(np.arange(64), 1024)
                                          .reshape(64, 1024))
            cell = g[r, c]
            for a, b in (("x", "sx"), ("y", "sy"), ("z", "sz")):
                np.testing.assert_array_equal(cell[a], sweep[b].astype(np.float32))
            np.testing.assert_array_equal(cell["range"], np.round(sweep["range"] * 1e3))
            if want == 2:
                n2 += len(sweep)
                # every non-zero cell of topic 2 is a second return: farther along the
                # same beam than the first return of that beam and column
                g1 = _grid(clouds["/ouster/points"][k][0])
                assert np.all(g1["range"][r, c] > 0)
                assert np.all(cell["range"] > g1["range"][r, c])
                nz = g["range"] > 0
                np.testing.assert_array_equal(nz, hit)
    assert n2 > 50


@pytest.fixture(scope="module")
def vlp(scene, traj, tmp_path_factory):
    d = tmp_path_factory.mktemp("vlp")
    out = {}
    for name, st_ in (("dual", DUSTY), ("single", Settings(particle_rate_per_m=0.05))):
        run = simulate_drive(scene, "velodyne_vlp16", traj, seed=3, t_end=T0 + 0.2,
                             settings=st_)
        _write(run, traj, d / f"{name}.mcap")
        out[name] = (run, np.concatenate(list(run)), _clouds(d / f"{name}.mcap"))
    return out


def test_the_velodyne_cloud_holds_both_returns_of_each_firing(vlp):
    run, pts, (clouds, counts) = vlp["dual"]
    assert set(clouds) == {"/velodyne_points"} and counts["/velodyne_points"] == 2
    rings = run.sensor.driver.rings(run.sensor.pattern.elevations_rad)
    dt = _dtype(VELODYNE, 22)
    n2 = 0
    for k, (msg, _raw) in enumerate(clouds["/velodyne_points"]):
        assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == \
            [(n, o, ROS_TYPE[t], 1) for n, o, t in VELODYNE]
        assert msg.point_step == 22 and msg.height == 1 and msg.is_dense
        c = np.frombuffer(np.asarray(msg.data, dtype=np.uint8).tobytes(), dtype=dt)
        sweep = pts[pts["frame"] == k]
        assert len(c) == len(sweep)               # every return of every pulse
        n2 += int((sweep["return_number"] == 2).sum())
        # Independent reference of the driver's order: for each firing (column) in
        # turn, its first returns in firing order, then its second returns.
        want = np.concatenate([
            sweep[(sweep["column"] == col) & (sweep["return_number"] == rn)]
            for col in np.unique(sweep["column"]) for rn in (1, 2)])
        for a, b in (("x", "sx"), ("y", "sy"), ("z", "sz")):
            np.testing.assert_array_equal(c[a], want[b].astype(np.float32))
        np.testing.assert_array_equal(c["ring"], rings[want["channel"]])
        np.testing.assert_array_equal(c["time"],
                                      (want["time"] - (T0 + k * 0.1)).astype(np.float32))
        # the two returns of a pulse are consecutive blocks of the same firing: the
        # second return of a beam lies after the first in the cloud, on the same ray
        rn = want["return_number"]
        assert set(np.unique(rn)) == {1, 2}
        for col in np.unique(want["column"][rn == 2])[:20]:
            idx = np.flatnonzero(want["column"] == col)
            assert (np.diff(rn[idx].astype(int)) >= 0).all()
    assert n2 > 50


def test_a_single_return_bag_is_unchanged(vlp):
    """The default path (no returns setting): one message per sweep whose data are,
    byte for byte, the driver's 22-byte points of the simulation's records in their
    own order (built here from the records), and no return topic."""
    run, pts, (clouds, counts) = vlp["single"]
    assert "return_number" not in (pts.dtype.names or ())
    assert set(clouds) == {"/velodyne_points"} and counts["/velodyne_points"] == 2
    rings = run.sensor.driver.rings(run.sensor.pattern.elevations_rad)
    dt = _dtype(VELODYNE, 22)
    for k, (msg, _raw) in enumerate(clouds["/velodyne_points"]):
        sweep = pts[pts["frame"] == k]
        want = np.zeros(len(sweep), dtype=dt)
        for a, b in (("x", "sx"), ("y", "sy"), ("z", "sz")):
            want[a] = sweep[b]
        want["intensity"] = sweep["intensity"].astype(np.float64) * 255.0
        want["ring"] = rings[sweep["channel"]]
        want["time"] = sweep["time"] - (T0 + k * 0.1)
        assert np.asarray(msg.data, dtype=np.uint8).tobytes() == want.tobytes()


def test_dual_records_stripped_to_return_1_give_the_single_return_bytes(os1, traj,
                                                                         tmp_path):
    """Return 1 of a dual drive written as POINT_DTYPE records (the single-return path)
    gives /ouster/points byte for byte as the dual bag does: the split changes
    nothing on the first topic."""
    from sensors.io.fields import POINT_DTYPE

    run, pts, (clouds, _counts) = os1
    first = pts[pts["return_number"] == 1]
    plain = np.empty(len(first), dtype=POINT_DTYPE)
    for n in POINT_DTYPE.names:
        plain[n] = first[n]
    path = tmp_path / "single.mcap"
    with open_writer(path, sensor=run.sensor, seed=run.seed, mount=run.mount,
                     trajectory=traj, span_s=(run.t0, run.t0 + run.duration_s)) as w:
        w.write_points(plain)
    single, counts = _clouds(path)
    assert set(single) == {"/ouster/points"} and "/ouster/points2" not in counts
    assert [raw for _m, raw in single["/ouster/points"]] == \
        [raw for _m, raw in clouds["/ouster/points"]]


def test_an_organised_driver_without_a_return_topic_refuses_dual(scene, traj, tmp_path):
    from sensors import PointFileError
    from sensors.spec import SPEC_DIR

    text = (SPEC_DIR / "ouster_os1_64.toml").read_text()
    p = tmp_path / "mine.toml"
    p.write_text(text.replace('dual_topic_suffix = "2"', ""))
    spec = load_sensor(p)
    run = simulate_drive(scene, spec, traj, seed=3, t_end=T0 + 0.1, settings=DUSTY)
    with pytest.raises(PointFileError, match="dual_topic_suffix.*--returns"):
        _write(run, traj, tmp_path / "x.mcap")
    assert not list(tmp_path.glob("x.mcap*"))


def test_a_bad_dual_topic_suffix_is_refused(tmp_path):
    from sensors import SensorSpecError
    from sensors.spec import SPEC_DIR

    text = (SPEC_DIR / "ouster_os1_64.toml").read_text()
    p = tmp_path / "mine.toml"
    p.write_text(text.replace('dual_topic_suffix = "2"', 'dual_topic_suffix = "-2"'))
    with pytest.raises(SensorSpecError, match="dual_topic_suffix"):
        load_sensor(p)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 5), st.integers(0, 3), st.integers(1, 2)),
                max_size=40, unique=True))
def test_returns_in_one_cloud_groups_firings_then_returns(keys):
    """Property: a permutation; columns non-decreasing; within a column the return
    numbers non-decreasing; records of one column and return keep their order."""
    rec = np.zeros(len(keys), dtype=RETURN_POINT_DTYPE)
    rec["column"] = [k[0] for k in keys]
    rec["channel"] = [k[1] for k in keys]
    rec["return_number"] = [k[2] for k in keys]
    rec["range"] = np.arange(len(keys))                  # the original position
    o = rec[returns_in_one_cloud(rec)]
    assert sorted(o["range"].tolist()) == list(range(len(keys)))
    key = o["column"].astype(int) * 10 + o["return_number"]
    assert (np.diff(key) >= 0).all()
    same = np.diff(key) == 0
    assert (np.diff(o["range"])[same] > 0).all()


def test_a_single_echo_mode_publishes_the_first_topic_alone(scene, traj, tmp_path):
    """`returns="strongest"`: one echo per pulse, as the device in a single-return
    profile: /ouster/points alone, its grid the simulation's returns."""
    from sensors.bag import RosbagStream

    run = simulate_drive(scene, "ouster_os1_64", traj, seed=3, t_end=T0 + 0.1,
                         settings=Settings(returns="strongest"))
    pts = np.concatenate(list(run))
    assert pts.dtype == RETURN_POINT_DTYPE and (pts["number_of_returns"] == 1).all()
    w = RosbagStream(tmp_path / "s.mcap", run.sensor, single_file=True, seed=run.seed,
                     trajectory=traj, span_s=(run.t0, run.t0 + run.duration_s),
                     returns="strongest")
    w.write_points(pts)
    w.close()
    clouds, counts = _clouds(tmp_path / "s.mcap")
    assert set(clouds) == {"/ouster/points"} and "/ouster/points2" not in counts
    g = _grid(clouds["/ouster/points"][0][0])
    assert (g["range"] > 0).sum() == (pts["frame"] == 0).sum() > 0


def test_a_return_mode_the_bag_does_not_know_is_refused(tmp_path):
    from sensors import PointFileError
    from sensors.bag import RosbagStream

    with pytest.raises(PointFileError, match="return mode.*--returns"):
        RosbagStream(tmp_path / "x.mcap", load_sensor("ouster_os1_64"), single_file=True,
                     returns="second")
    assert not list(tmp_path.iterdir())


def test_drive_returns_dual_writes_the_ouster_return_topic(tmp_path, monkeypatch):
    """Through the CLI: `drive --returns dual -o x.mcap` gives /ouster/points2 beside
    /ouster/points, one message each per sweep; every cell with a second return has a
    first return of the same beam and column, nearer; without --returns no
    /ouster/points2."""
    from survey.cli.main import main

    monkeypatch.chdir(tmp_path)
    assert main(["tunnel", "-o", "t.ply", "--preset", "bfo", "--edge-length", "0.5",
                 "--quiet"]) == 0
    drive = ["drive", "--mesh", "t.ply", "--sensor", "ouster_os1_64", "--along",
             "centreline", "--speed", "2", "--duration", "0.2", "--particles", "0.05",
             "--seed", "3", "--quiet"]
    assert main(drive + ["--returns", "dual", "-o", "dual.mcap"]) == 0
    assert main(drive + ["-o", "plain.mcap"]) == 0
    # a single-echo mode keeps the one topic: the drive tells the bag its mode
    assert main(drive + ["--returns", "strongest", "-o", "strongest.mcap"]) == 0
    _, counts_s = _clouds("strongest.mcap")
    assert "/ouster/points2" not in counts_s and counts_s["/ouster/points"] == 2
    clouds, counts = _clouds("dual.mcap")
    assert counts["/ouster/points"] == counts["/ouster/points2"] == 2
    n2 = 0
    for (m1, _r1), (m2, _r2) in zip(clouds["/ouster/points"], clouds["/ouster/points2"]):
        g1, g2 = _grid(m1), _grid(m2)
        two = g2["range"] > 0
        n2 += int(two.sum())
        assert np.all(g1["range"][two] > 0) and np.all(g2["range"][two] > g1["range"][two])
        # the same beam: the two points lie on one ray from the sensor
        p1 = np.stack([g1["x"][two], g1["y"][two], g1["z"][two]], 1).astype(np.float64)
        p2 = np.stack([g2["x"][two], g2["y"][two], g2["z"][two]], 1).astype(np.float64)
        u1 = p1 / np.linalg.norm(p1, axis=1, keepdims=True)
        u2 = p2 / np.linalg.norm(p2, axis=1, keepdims=True)
        assert np.allclose(u1, u2, atol=1e-5)
    assert n2 > 50
    plain, counts = _clouds("plain.mcap")
    assert set(plain) == {"/ouster/points"} and "/ouster/points2" not in counts


def test_the_airy_cloud_holds_both_returns_in_its_layout(scene, traj, tmp_path):
    """rslidar_sdk: both returns in /rslidar_points, the 26-byte layout, the returns of
    each firing together (return 1 first: ASSUMED, see robosense_airy.toml)."""
    run = simulate_drive(scene, "robosense_airy", traj, seed=3, t_end=T0 + 0.1,
                         settings=DUSTY)
    pts = np.concatenate(list(run))
    _write(run, traj, tmp_path / "a.mcap")
    clouds, counts = _clouds(tmp_path / "a.mcap")
    assert set(clouds) == {"/rslidar_points"}
    dt = _dtype([("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 12, "f4"),
                 ("ring", 16, "u2"), ("timestamp", 18, "f8")], 26)
    n2 = 0
    for k, (msg, _raw) in enumerate(clouds["/rslidar_points"]):
        assert msg.point_step == 26
        c = np.frombuffer(np.asarray(msg.data, dtype=np.uint8).tobytes(), dtype=dt)
        sweep = pts[pts["frame"] == k]
        want = np.concatenate([
            sweep[(sweep["column"] == col) & (sweep["return_number"] == rn)]
            for col in np.unique(sweep["column"]) for rn in (1, 2)])
        n2 += int((want["return_number"] == 2).sum())
        np.testing.assert_array_equal(c["x"], want["sx"].astype(np.float32))
        np.testing.assert_array_equal(c["timestamp"], want["time"])
    assert n2 > 20
