"""Writers: LAZ/LAS read back by laspy, E57 by pye57, PLY by trimesh, NPZ by numpy; a
georeferenced tunnel keeps 0.1 mm; an interrupted write leaves nothing behind."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import (
    PointFileError,
    Settings,
    Trajectory,
    simulate_drive,
    simulate_station,
)

from sensors.io.fields import FILE_NAMES

UTM = np.array([451_234.0, 5_352_876.0, 612.0])


@pytest.fixture(scope="module")
def utm_scene():
    v, f = tunnel_tube(20_000, length_m=60.0)
    return Scene(v + UTM, f)


def _station(scene, **kw):
    return simulate_station(scene, "zf_imager_5016", UTM + [30.0, 0.0, 1.5],
                            resolution="preview", seed=7, **kw)


@pytest.fixture(scope="module")
def points(utm_scene):
    return np.concatenate(list(_station(utm_scene)))


@pytest.mark.parametrize("suffix", ["laz", "las"])
def test_las_round_trip_keeps_a_tenth_of_a_millimetre(utm_scene, points, tmp_path, suffix):
    path = tmp_path / f"s.{suffix}"
    stats = _station(utm_scene).write(path, fields="full")
    assert stats["points"] == len(points)
    las = laspy.read(path)
    assert las.header.version.minor == 4 and las.header.point_format.id == 6
    assert len(las.points) == len(points)
    for axis in "xyz":
        err = np.abs(np.asarray(las[axis]) - points[axis])
        assert err.max() <= 0.5e-4 + 1e-9               # half the 0.1 mm scale
    np.testing.assert_array_equal(las.gps_time, points["time"])
    # range is float32 in LAS since issue 30 (sensors.io.fields): the nearest float32,
    # within half its 2^-23 relative step of the float64 value.
    assert las["range"].dtype == np.float32
    np.testing.assert_array_equal(las["range"], points["range"].astype(np.float32))
    assert (np.abs(las["range"] - points["range"]) <= 2.0**-24 * points["range"]).all()
    np.testing.assert_array_equal(las["triangle"], points["triangle"])
    np.testing.assert_array_equal(las.intensity, np.round(points["intensity"] * 65535))
    assert np.all(las.return_number == 1)
    import json
    vlr = las.header.vlrs.get_by_id("tunnelsim", [1])[0]
    info = json.loads(vlr.record_data)
    assert info["station_position"] == (UTM + [30.0, 0.0, 1.5]).tolist()
    compact = laspy.read(_station(utm_scene).write(tmp_path / f"c.{suffix}")["path"])
    assert set(compact.point_format.extra_dimension_names) == {"channel", "column",
                                                                "triangle", "flag"}
    np.testing.assert_array_equal(compact.X, las.X)


def test_e57_round_trip_with_the_station_pose(utm_scene, tmp_path):
    import pye57

    att = Rotation.from_euler("z", 20, degrees=True)
    pts = np.concatenate(list(_station(utm_scene, attitude=att)))
    path = tmp_path / "s.e57"
    _station(utm_scene, attitude=att).write(path)
    e57 = pye57.E57(str(path))
    raw = e57.read_scan_raw(0)
    head = e57.get_header(0)
    local = np.stack([raw["cartesianX"], raw["cartesianY"], raw["cartesianZ"]], 1)
    world = local @ head.rotation_matrix.T + head.translation
    np.testing.assert_allclose(world, np.stack([pts["x"], pts["y"], pts["z"]], 1), atol=1e-6)
    np.testing.assert_array_equal(raw["rowIndex"], pts["channel"])
    np.testing.assert_array_equal(raw["columnIndex"], pts["column"])


def test_e57_is_for_stations_only(utm_scene, tmp_path):
    traj = Trajectory.static(UTM + [30, 0, 1.5])
    run = simulate_drive(utm_scene, "velodyne_vlp16", traj, t_end=0.05)
    with pytest.raises(PointFileError, match="TLS station"):
        run.write(tmp_path / "d.e57")
    assert not list(tmp_path.iterdir())


def test_ply_and_npz_round_trip(utm_scene, points, tmp_path):
    _station(utm_scene).write(tmp_path / "s.ply")
    cloud = trimesh.load(tmp_path / "s.ply")
    np.testing.assert_array_equal(cloud.vertices, np.stack([points["x"], points["y"],
                                                            points["z"]], 1))
    _station(utm_scene, chunk_pulses=100_000).write(tmp_path / "s.npz")  # other chunking
    back = np.load(tmp_path / "s.npz")
    for name in points.dtype.names:            # under the file names (sensors.io.fields)
        np.testing.assert_array_equal(back[FILE_NAMES[name]], points[name])


def test_interrupted_write_leaves_no_file(utm_scene, tmp_path):
    calls = []

    def stop(done, total):
        calls.append(done)
        raise KeyboardInterrupt

    for suffix in ("laz", "ply", "npz"):
        with pytest.raises(KeyboardInterrupt):
            _station(utm_scene, chunk_pulses=50_000).write(tmp_path / f"s.{suffix}",
                                                             progress=stop)
    assert calls and not list(tmp_path.iterdir())


def test_bad_output(utm_scene, tmp_path):
    with pytest.raises(PointFileError, match="format"):
        _station(utm_scene).write(tmp_path / "s.xyz")
    with pytest.raises(PointFileError, match="existing output folder"):
        _station(utm_scene).write(tmp_path / "no" / "s.laz")


def test_ideal_station_points_lie_on_the_mesh(utm_scene):
    """With the physics off, the written world points are the mesh hit points: cast
    again from the station through each point and land on it."""
    pts = np.concatenate(list(_station(utm_scene, settings=Settings.ideal())))
    p = np.stack([pts["x"], pts["y"], pts["z"]], 1)[::50]
    o = UTM + [30.0, 0.0, 1.5]
    hits = utm_scene.cast(o, p - o)
    np.testing.assert_allclose(hits.points, p, atol=1e-7)


# ---------------------------------------------------------------- the stream API
def _chunk(n, seed=0):
    from sensors import POINT_DTYPE

    rng = np.random.default_rng(seed)
    c = np.zeros(n, dtype=POINT_DTYPE)
    for name in POINT_DTYPE.names:
        c[name] = rng.uniform(0, 100, n).astype(POINT_DTYPE[name])
    c["x"] += UTM[0]
    c["flag"] = rng.integers(1, 4, n)
    return c


def test_open_writer_records_what_it_is_given(tmp_path):
    """A writer is given the sensor's name, the seed and the pose, and stores them: in
    the LAS VLR, in the PLY comments."""
    import json

    from sensors import open_writer

    rot = Rotation.from_euler("z", 0.3)
    parts = [_chunk(500, 1), _chunk(0), _chunk(700, 2)]
    for suffix in ("laz", "ply"):
        with open_writer(tmp_path / f"w.{suffix}", sensor="my_scanner", seed=11,
                         pose=(UTM, rot)) as w:
            for c in parts:
                w.write_points(c)
        assert w.n_points == 1200 and "1,200 points" in repr(w)
    whole = np.concatenate(parts)
    las = laspy.read(tmp_path / "w.laz")
    info = json.loads(las.header.vlrs.get_by_id("tunnelsim", [1])[0].record_data)
    assert info["sensor"] == "my_scanner" and info["seed"] == 11
    np.testing.assert_allclose(info["station_quaternion_xyzw"], rot.as_quat())
    np.testing.assert_array_equal(las.gps_time, whole["time"])
    assert set(las.point_format.extra_dimension_names) == {
        "channel", "column", "triangle", "flag"}            # compact with a pose
    np.testing.assert_array_equal(las.classification, np.where(whole["flag"] == 2, 7, 0))
    ply = (tmp_path / "w.ply").read_bytes()
    assert b"comment tunnelsim my_scanner" in ply and b'"seed": 11' in ply
    cloud = trimesh.load(tmp_path / "w.ply")
    np.testing.assert_array_equal(cloud.vertices[:, 0], whole["x"])


def test_open_writer_refuses_what_it_cannot_store(tmp_path):
    from sensors import open_writer

    with pytest.raises(PointFileError, match="TLS station"):
        open_writer(tmp_path / "a.e57", sensor="s")
    with pytest.raises(PointFileError, match="fields 'full' or 'compact'"):
        open_writer(tmp_path / "a.laz", sensor="s", fields="all")
    with pytest.raises(PointFileError, match="at most 50,000,000 pulses"):
        open_writer(tmp_path / "a.e57", sensor="s", pose=(UTM, Rotation.identity()),
                    expected_points=60_000_000)
    with open_writer(tmp_path / "a.npz", sensor="s") as w:
        with pytest.raises(PointFileError, match="fields of POINT_DTYPE"):
            w.write_points(np.zeros(3, dtype=[("x", "f8")]))
        w.abort()
    with pytest.raises(PointFileError, match="closed one"):
        w.write_points(_chunk(2))
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("suffix", ["las", "laz", "ply", "npz", "e57"])
def test_an_exception_inside_the_writer_leaves_nothing(tmp_path, suffix):
    from sensors import open_writer

    with pytest.raises(RuntimeError), open_writer(tmp_path / f"a.{suffix}", sensor="s",
                                                  pose=(UTM, Rotation.identity())) as w:
        w.write_points(_chunk(100))
        raise RuntimeError("simulated crash")
    assert not list(tmp_path.iterdir())
