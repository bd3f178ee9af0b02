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
from sensors import (PointFileError, Settings, Trajectory, simulate_drive,
                     simulate_station)

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
    np.testing.assert_array_equal(las["range"], points["range"])
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
    for name in points.dtype.names:
        np.testing.assert_array_equal(back[name], points[name])


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
