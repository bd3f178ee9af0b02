"""ROS 2 bags (issue 30): a chosen epoch for the stamps (``start_time_ns``,
``--start-time``), and the rosbag2 metadata of Humble (version 5) and Jazzy (version 9),
both read back by rosbags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import PointFileError, Trajectory, load_sensor, simulate_drive
from sensors.bag import METADATA_VERSIONS, RosbagStream, parse_start_time

pytest.importorskip("rosbags", reason="rosbags is in the test extra")
from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.rosbag2 import Reader  # noqa: E402
from ruamel.yaml import YAML  # noqa: E402

T0 = 100.0
EPOCH = "2024-05-01T12:00:00Z"
EPOCH_NS = 1_714_564_800 * 10 ** 9          # date -d 2024-05-01T12:00:00Z +%s


@pytest.fixture(scope="module")
def scene():
    v, f = tunnel_tube(4_000, length_m=30.0, seed=3)
    return Scene(v, f)


@pytest.fixture(scope="module")
def traj():
    return Trajectory.along_polyline([[5.0, 0.0, 1.4], [20.0, 0.0, 1.4]], 2.0, rate_hz=100,
                                     start_time=T0)


def _write(run, traj, path, *, single=True, **kw):
    w = RosbagStream(path, run.sensor, single_file=single, seed=run.seed, mount=run.mount,
                     trajectory=traj, span_s=(run.t0, run.t0 + run.duration_s), **kw)
    for chunk in run:
        w.write_points(chunk)
    w.close()
    return path


def _messages(path):
    with AnyReader([Path(path)]) as r:
        return [(c.topic, t, r.deserialize(raw, c.msgtype))
                for c, t, raw in r.messages()]


def _ns(stamp):
    return stamp.sec * 10 ** 9 + stamp.nanosec


def test_parse_start_time():
    assert parse_start_time(EPOCH) == EPOCH_NS
    assert parse_start_time("2024-05-01T14:00:00+02:00") == EPOCH_NS
    assert parse_start_time("1714564800.000000001") == EPOCH_NS + 1
    assert parse_start_time("2024-05-01T12:00:00.000250Z") == EPOCH_NS + 250_000
    for bad in ("2024-05-01T12:00:00", "yesterday", "-1", "nan", ""):
        with pytest.raises(PointFileError, match="--start-time"):
            parse_start_time(bad)


@pytest.mark.parametrize("sensor", ["velodyne_vlp16", "robosense_airy"])
def test_stamps_start_at_the_chosen_epoch(scene, traj, tmp_path, sensor):
    """Sweep k stamped EPOCH + k 0.1 s and logged at its end, /tf every 10 ms, the IMU
    every 5 ms from EPOCH: the scan's start (T0 in the trajectory) is the epoch."""
    run = simulate_drive(scene, sensor, traj, seed=2, t_end=T0 + 0.3)
    msgs = _messages(_write(run, traj, tmp_path / "e.mcap", start_time_ns=EPOCH_NS))
    topic = run.sensor.driver.topic
    clouds = [(t, m) for tp, t, m in msgs if tp == topic]
    assert len(clouds) == 3
    for k, (log, m) in enumerate(clouds):
        assert _ns(m.header.stamp) == EPOCH_NS + k * 100_000_000
        assert log == EPOCH_NS + (k + 1) * 100_000_000
    tf = [_ns(m.transforms[0].header.stamp) for tp, _t, m in msgs if tp == "/tf"]
    assert tf == [EPOCH_NS + j * 10_000_000 for j in range(31)]
    imu = [_ns(m.header.stamp) for tp, _t, m in msgs if tp == "/imu/data_raw"]
    assert imu == [EPOCH_NS + j * 5_000_000 for j in range(61)]
    static = next(m for tp, _t, m in msgs if tp == "/tf_static")
    assert all(_ns(tf.header.stamp) == EPOCH_NS for tf in static.transforms)
    if sensor == "robosense_airy":      # the layout's absolute point times shift too
        from tests.sensors.test_bag import _points

        pts = np.concatenate(list(run))
        cloud = _points(clouds[1][1])
        ref = pts[pts["frame"] == 1]["time"] - T0 + EPOCH_NS * 1e-9
        # float64 seconds near 1.7e9 s resolve 0.24 us
        assert np.abs(cloud["timestamp"] - ref).max() < 1e-6
    else:
        assert all(m.header.frame_id == "velodyne" for _l, m in clouds)


def test_an_epoch_lets_a_trajectory_start_before_zero(scene, tmp_path):
    early = Trajectory.along_polyline([[5.0, 0.0, 1.4], [20.0, 0.0, 1.4]], 2.0,
                                      start_time=-1.0)
    run = simulate_drive(scene, "velodyne_vlp16", early, t_end=-0.8)
    with pytest.raises(PointFileError, match="--start-time"):
        _write(run, early, tmp_path / "neg.mcap")
    msgs = _messages(_write(run, early, tmp_path / "ok.mcap", start_time_ns=EPOCH_NS))
    logs = [t for _tp, t, _m in msgs]
    assert min(logs) == EPOCH_NS and logs == sorted(logs)


def _meta(path):
    return YAML(typ="safe").load((path / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"]


def test_humble_and_jazzy_metadata_read_back_alike(scene, traj, tmp_path):
    run = simulate_drive(scene, "velodyne_vlp16", traj, seed=2, t_end=T0 + 0.2)
    bags = {d: _write(run, traj, tmp_path / f"bag_{d}", single=False, ros_distro=d)
            for d in ("humble", "jazzy")}
    humble, jazzy = _meta(bags["humble"]), _meta(bags["jazzy"])
    assert (humble["version"], jazzy["version"]) == (5, 9) == \
        (METADATA_VERSIONS["humble"], METADATA_VERSIONS["jazzy"])
    # Humble's version 5: no keys of 6 and later; QoS profiles one YAML string of
    # policy numbers (rosbag2 0.15). Jazzy's 9: a list with policy names.
    assert "custom_data" not in humble and "ros_distro" not in humble
    assert "tunnelsim" in jazzy["custom_data"]
    for h, j in zip(humble["topics_with_message_count"],
                    jazzy["topics_with_message_count"], strict=True):
        ht, jt = h["topic_metadata"], j["topic_metadata"]
        assert "type_description_hash" not in ht and "type_description_hash" in jt
        assert h["message_count"] == j["message_count"] > 0
        hq, jq = ht["offered_qos_profiles"], jt["offered_qos_profiles"]
        assert isinstance(hq, str) and isinstance(jq, list)
        if ht["name"] == "/tf_static":
            q = YAML(typ="safe").load(hq)[0]
            assert (q["durability"], jq[0]["durability"]) == (1, "transient_local")
    for key in ("storage_identifier", "message_count", "duration", "starting_time"):
        assert humble[key] == jazzy[key], key
    for d, meta in (("humble", humble), ("jazzy", jazzy)):
        assert meta["relative_file_paths"] == [f["path"] for f in meta["files"]] == \
            [f"bag_{d}.mcap"]
    # both read back by rosbags' rosbag2 reader, message for message
    read = {}
    for d, path in bags.items():
        with Reader(path) as r:
            assert r.message_count == humble["message_count"]
            qos = {c.topic: c.ext.offered_qos_profiles for c in r.connections}
            assert qos["/tf_static"][0].durability.name == "TRANSIENT_LOCAL"
            read[d] = [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in r.messages()]
    assert read["humble"] == read["jazzy"] and len(read["humble"]) > 50


def test_bad_distro_and_epoch_are_refused(tmp_path):
    spec = load_sensor("velodyne_vlp16")
    with pytest.raises(PointFileError, match="--ros-distro humble or jazzy"):
        RosbagStream(tmp_path / "a", spec, single_file=False, ros_distro="iron")
    with pytest.raises(PointFileError, match="--start-time"):
        RosbagStream(tmp_path / "b.mcap", spec, single_file=True, start_time_ns=-5)
    assert not list(tmp_path.iterdir())
