"""One field naming across LAS/LAZ, PLY and NPZ (issue 22), files of earlier versions
still read, and the fast write paths (one-pass LAS records, the writer thread) giving
the bytes of the plain ones.

References are independent of the code under test: the expected names are written out
here, LAS files are read by laspy, PLY by the raw bytes NumPy maps, NPZ by numpy.load;
the one-pass LAS records are compared with ``point_records`` (field by field NumPy
assignment), the threaded files with unthreaded ones.
"""

from __future__ import annotations

import hashlib

import laspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import POINT_DTYPE, PointFileError, Trajectory, open_writer, simulate_drive
from sensors.io.fields import FILE_FIELDS, FILE_NAMES, file_records, point_field
from sensors.io.las import LasRecords, point_records
from sensors.io.ply import PlyWriter, read_ply, read_ply_header

#: The names every format uses (issue 22), written out as the README states them.
NAMES = {"x", "y", "z", "sensor_x", "sensor_y", "sensor_z", "range", "azimuth",
         "elevation", "gps_time", "channel", "column", "frame", "intensity", "incidence",
         "triangle", "flag"}
#: LAS point format 6 dimensions that hold a POINT_DTYPE field under its file name.
LAS_STANDARD = {"gps_time", "intensity"}


@pytest.fixture(scope="module")
def drive():
    v, f = tunnel_tube(4_000, length_m=40.0)
    scene = Scene(v, f)
    traj = Trajectory.along_polyline(np.array([[5.0, 0, 1.5], [15.0, 0, 1.5]]), 2.0)

    def run(chunk_pulses=40_000):
        return simulate_drive(scene, "velodyne_vlp16", traj, seed=3, t_end=0.25,
                              chunk_pulses=chunk_pulses)
    return run


@pytest.fixture(scope="module")
def points(drive):
    return np.concatenate(list(drive()))


def _las_names(las) -> set[str]:
    """The file names of a LAS file: x, y, z (scaled X, Y, Z), the standard dimensions
    that hold a field, and the extra bytes."""
    return {"x", "y", "z"} | (LAS_STANDARD & set(las.point_format.dimension_names)) | \
        set(las.point_format.extra_dimension_names)


def test_las_npz_and_ply_name_every_field_alike(drive, points, tmp_path):
    for suffix in ("laz", "npz", "ply"):
        drive().write(tmp_path / f"d.{suffix}", fields="full")
    las = laspy.read(tmp_path / "d.laz")
    npz = np.load(tmp_path / "d.npz")
    ply = read_ply(tmp_path / "d.ply")["vertex"]
    assert _las_names(las) == set(npz.files) == set(ply.dtype.names) == NAMES
    assert set(FILE_NAMES.values()) == NAMES
    # Values: NPZ and PLY hold POINT_DTYPE's values; LAS its quantised ones.
    for f in FILE_FIELDS:
        np.testing.assert_array_equal(npz[f.name], points[f.field])
        np.testing.assert_array_equal(ply[f.name], points[f.field])
        if f.las not in ("xyz", "standard"):
            # LAS holds each extra field in its stated type (sensor_x..range float32
            # since issue 30): the value NumPy's round-to-nearest cast gives.
            assert las[f.name].dtype == np.dtype(f.las)
            np.testing.assert_array_equal(np.asarray(las[f.name]),
                                          points[f.field].astype(f.las))
    np.testing.assert_array_equal(las.gps_time, points["time"])
    np.testing.assert_array_equal(las.intensity, np.round(points["intensity"] * 65535))
    for a in "xyz":
        assert np.abs(np.asarray(las[a]) - points[a]).max() <= 0.5e-4 + 1e-9


def test_point_field_reads_new_and_old_names():
    for f in FILE_FIELDS:
        assert point_field(f.name) == f.field and point_field(f.old_name) == f.field
    assert (point_field("sensor_x"), point_field("sx")) == ("sx", "sx")
    assert (point_field("gps_time"), point_field("time")) == ("time", "time")
    assert point_field("red") is None


def _old_ply(path, pts):
    """A PLY as tunnelsim wrote it before the one naming: POINT_DTYPE's names."""
    with PlyWriter(path, [("vertex", POINT_DTYPE, None)],
                   comments=["tunnelsim velodyne_vlp16"]) as w:
        w.write("vertex", pts)


@pytest.mark.parametrize("old", [False, True])
def test_a_rewrite_reads_the_time_under_either_name(drive, points, tmp_path, old):
    from sensors.io.cloudmap import map_cloud

    src = tmp_path / "d.ply"
    if old:
        _old_ply(src, points)
        assert "time" in read_ply_header(src).element("vertex").dtype.names
    else:
        drive().write(src)
    seen = []

    def shift(xyz, t):
        seen.append(t)
        return xyz + 1.0

    map_cloud(src, tmp_path / "o.ply", shift)
    np.testing.assert_array_equal(np.concatenate(seen), points["time"])


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(0, 3000), seed=st.integers(0, 2**31), sub=st.booleans())
def test_file_records_keep_every_value(n, seed, sub):
    rng = np.random.default_rng(seed)
    pts = np.zeros(n, POINT_DTYPE)
    for name in POINT_DTYPE.names:
        pts[name] = rng.uniform(-1e3, 1e3, n).astype(POINT_DTYPE[name])
    src = pts[::2] if sub else pts          # a strided view too
    got = file_records(src)
    for f in FILE_FIELDS:
        np.testing.assert_array_equal(got[f.name], src[f.field])


def _header(extra):
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales = np.full(3, 1e-4)
    h.offsets = np.array([451_000.0, 5_352_000.0, 0.0])
    h.add_extra_dims([laspy.ExtraBytesParams(name=n, type=np.dtype(t)) for n, t in extra])
    return h


@settings(max_examples=25, deadline=None)
@given(n=st.integers(1, 2000), seed=st.integers(0, 2**31))
def test_one_pass_las_records_equal_field_by_field_ones(n, seed):
    """LasRecords (computed dimensions + byte copies) == point_records (NumPy
    assignment, with its casts: int32 -> uint32 of negative values included)."""
    rng = np.random.default_rng(seed)
    pts = np.zeros(n, POINT_DTYPE)
    for name in POINT_DTYPE.names:
        pts[name] = rng.uniform(-5e3, 5e3, n).astype(POINT_DTYPE[name])
    pts["x"] += 451_234.0
    pts["y"] += 5_352_876.0
    extra = [("sensor_x", "f8"), ("range", "f8"), ("azimuth", "f4"), ("channel", "u4"),
             ("frame", "u4"), ("triangle", "i4"), ("flag", "u1")]
    copies = {"sensor_x": "sx", "range": "range", "azimuth": "azimuth",
              "channel": "channel", "frame": "frame", "triangle": "triangle",
              "flag": "flag"}
    fields = {"gps_time": pts["time"], "intensity": np.round(pts["intensity"] * 65535),
              "bit_fields": 0x11, "user_data": pts["channel"] % 256}
    h = _header(extra)
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], 1)
    want = point_records(h, xyz, dict(fields, **{k: pts[v] for k, v in copies.items()}))
    rec = LasRecords(h)
    rec.fill(xyz[:1], {})                       # a reused, larger buffer next time
    got = rec.fill((pts["x"], pts["y"], pts["z"]), fields, records=pts, copies=copies)
    assert got.array.tobytes() == want.array.tobytes()


def test_las_records_refuse_unknown_dimensions_and_bad_coordinates():
    rec = LasRecords(_header([("flag", "u1")]))
    with pytest.raises(PointFileError, match=r"got \['colour'\]"):
        rec.fill(np.zeros((2, 3)), {"colour": 1})
    with pytest.raises(PointFileError, match="point 1"):
        rec.fill(np.array([[451_000.0, 5_352_000, 0], [np.nan, 5_352_000, 0]]))


def _md5(path) -> str:
    return hashlib.md5(path.read_bytes()).hexdigest()


def _write(drive, path, chunk, thread):
    with open_writer(path, sensor="velodyne_vlp16", seed=3, fields="full",
                     thread=thread) as w:
        for c in drive(chunk):
            w.write_points(c)
    assert w.threaded is thread
    return path


@pytest.mark.parametrize("suffix", ["las", "laz", "ply"])
def test_the_thread_leaves_the_bytes_alone(drive, tmp_path, suffix):
    a = _write(drive, tmp_path / f"a.{suffix}", 13_000, True)
    b = _write(drive, tmp_path / f"b.{suffix}", 13_000, False)
    assert _md5(a) == _md5(b)


@pytest.mark.parametrize("suffix", ["las", "laz", "ply"])
def test_chunking_leaves_the_points_alone(drive, tmp_path, suffix):
    """Other chunks, with and without the thread: PLY the same bytes, LAS/LAZ the same
    point records. (laspy's extra-bytes min/max in the LAS header depend on the
    chunking, as they did before the writer thread: not a global min/max.)"""
    a = _write(drive, tmp_path / f"a.{suffix}", 13_000, True)
    b = _write(drive, tmp_path / f"b.{suffix}", 40_000, False)
    if suffix == "ply":
        assert _md5(a) == _md5(b)
        return
    la, lb = laspy.read(a), laspy.read(b)
    assert la.points.array.tobytes() == lb.points.array.tobytes()
    if suffix == "las":
        start = la.header.offset_to_point_data
        assert a.read_bytes()[start:] == b.read_bytes()[start:]


def test_thread_and_chunking_leave_npz_arrays_alone(drive, points, tmp_path):
    for thread, chunk in ((True, 13_000), (False, 40_000)):
        with open_writer(tmp_path / f"{thread}.npz", sensor="s", thread=thread) as w:
            for c in drive(chunk):
                w.write_points(c)
    a, b = np.load(tmp_path / "True.npz"), np.load(tmp_path / "False.npz")
    assert a.files == b.files
    for k in a.files:
        assert a[k].dtype == b[k].dtype
        np.testing.assert_array_equal(a[k], b[k])


@pytest.mark.parametrize("suffix", ["las", "laz", "ply", "npz"])
def test_an_error_on_the_writer_thread_reaches_the_caller(points, tmp_path, suffix):
    """The thread's exception is raised by the next write or by close, and no file (nor
    temporary) is left."""
    bad = points[:500].copy()
    bad["x"][7] = np.nan if suffix in ("las", "laz") else bad["x"][7]
    with pytest.raises(PointFileError, match="point 7"), \
            open_writer(tmp_path / f"a.{suffix}", sensor="s") as w:
        w.write_points(points[:1000])
        w.write_points(bad)
        if suffix in ("ply", "npz"):           # nothing there fails: fail it here
            raise PointFileError("Expected nothing, got point 7.")
        for _ in range(50):                    # the error arrives on one of these
            w.write_points(points[:10])
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("kind", ["laz", "ply", "npz", "old.ply"])
def test_a_drive_reads_back_in_every_format_and_naming(drive, points, tmp_path, kind):
    """open_drive/iter_frames give the frames of the points in memory
    (frames_from_points) from LAZ, PLY and NPZ, and from a PLY of earlier versions."""
    from survey.clouds.drives import frames_from_points, iter_frames, open_drive

    path = tmp_path / f"d.{kind}"
    if kind == "old.ply":
        _old_ply(path, points)
    else:
        drive().write(path, fields="full")
    d = open_drive(path)
    assert d.n_points == len(points)
    assert d.time_span_s == (points["time"].min(), points["time"].max())
    assert d.mount_recorded is (kind in ("laz", "ply"))
    want = list(frames_from_points([points]))
    got = list(iter_frames(d, chunk=7_000))           # frames split over chunks
    assert [f.frame for f in got] == [f.frame for f in want] and len(want) > 1
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g.times, w.times)
        if kind == "laz":   # sensor_x.. are float32 in LAS (issue 30): 2^-24 relative
            np.testing.assert_allclose(g.points, w.points, rtol=2.0**-24, atol=0)
        else:
            np.testing.assert_array_equal(g.points, w.points)


def test_a_drive_without_sensor_fields_is_refused(points, tmp_path):
    from survey.clouds.drives import open_drive
    from sensors.io.errors import PointFileError

    np.savez(tmp_path / "x.npz", x=points["x"], gps_time=points["time"])
    with pytest.raises(PointFileError, match="sensor-frame fields"):
        open_drive(tmp_path / "x.npz")
