"""Compact LAZ for drives (issue 30): sensor_x, sensor_y, sensor_z and range are stored
as float32 extra bytes; the NPZ of the same drive keeps float64.

References: the NPZ of the same seeded drive (float64, read by numpy.load), laspy's own
reading of the LAZ, float32's rounding bound (IEEE 754: nearest float32, within half its
2^-23 relative step), the truth trajectory file and the mount the file records (world =
pose o mount o sensor point), and a LAZ written with the float64 types of earlier
versions, which readers must still take.
"""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import sensors.writers
from sensors import Trajectory
from sensors.io.fields import LAS_EXTRA, LAS_EXTRA_F8
from sensors.io.las import LasRecords
from survey.cli.main import main
from survey.clouds.drives import frames_from_points, iter_frames, open_drive

COMPACT = ("sensor_x", "sensor_y", "sensor_z", "range")


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    """The same VLP-16 drive (seed 5, a lever arm) written as LAZ and as NPZ."""
    d = tmp_path_factory.mktemp("laz")
    assert main(["tunnel", "--preset", "bfo", "--edge-length", "0.5", "-o",
                 str(d / "t.ply"), "--quiet"]) == 0
    common = ["drive", "--mesh", str(d / "t.ply"), "--sensor", "velodyne_vlp16",
              "--along", "centreline", "--speed", "2", "--chainage", "5,7",
              "--lever", "0.2,0.05,0.3", "--seed", "5", "--fields", "full", "--quiet"]
    assert main([*common, "-o", str(d / "v.laz")]) == 0
    assert main([*common, "-o", str(d / "v.npz")]) == 0
    return d


def test_laz_holds_float32_sensor_fields_within_their_precision(drive):
    las = laspy.read(drive / "v.laz")
    npz = np.load(drive / "v.npz")
    assert len(las.points) == len(npz["sensor_x"]) > 1000
    for name in COMPACT:
        assert las.point_format.dimension_by_name(name).dtype == np.float32
        assert npz[name].dtype == np.float64
        got, want = np.asarray(las[name]), npz[name]
        # Nearest float32: within half the 2^-23 relative step, never beyond 31 um
        # below 512 m (the bound sensors.io.fields states).
        assert (np.abs(got - want) <= 2.0**-24 * np.abs(want)).all()
        assert np.abs(got - want).max() <= 31e-6
        assert np.abs(got - want).max() > 0      # float32 indeed (not a float64 copy)
    for name in ("channel", "column", "frame", "triangle", "flag"):   # exact types
        np.testing.assert_array_equal(np.asarray(las[name]), npz[name])


def test_world_point_is_pose_mount_sensor_point_from_the_files(drive):
    """World = pose(t) o mount o sensor point, from the LAZ, its recorded mount and the
    truth trajectory written beside it, to the 0.1 mm LAS scale (plus float32's
    rounding of the sensor point)."""
    las = laspy.read(drive / "v.laz")
    d = open_drive(drive / "v.laz")
    assert d.mount_recorded and d.mount.lever_arm_m == (0.2, 0.05, 0.3)
    truth = Trajectory.read(drive / "v_true_trajectory.txt")
    pos, mat = truth.sensor_matrices(np.asarray(las.gps_time), d.mount)
    s = np.stack([np.asarray(las[n], dtype=np.float64) for n in COMPACT[:3]], 1)
    world = pos + np.einsum("nij,nj->ni", mat, s)
    assert np.abs(world - np.stack([las.x, las.y, las.z], 1)).max() < 1e-4


def test_old_float64_laz_and_new_float32_laz_both_read(drive, tmp_path, monkeypatch):
    """A LAZ written with the float64 extra bytes of earlier versions reads as the NPZ
    exactly; the float32 one within float32's step."""
    monkeypatch.setattr(sensors.writers, "LAS_EXTRA", LAS_EXTRA_F8)
    assert main(["drive", "--mesh", str(drive / "t.ply"), "--sensor", "velodyne_vlp16",
                 "--along", "centreline", "--speed", "2", "--chainage", "5,7",
                 "--lever", "0.2,0.05,0.3", "--seed", "5", "--fields", "full",
                 "--quiet", "-o", str(tmp_path / "old.laz")]) == 0
    monkeypatch.undo()
    old = laspy.read(tmp_path / "old.laz")
    assert old.point_format.dimension_by_name("sensor_x").dtype == np.float64
    npz = np.load(drive / "v.npz")
    rec = np.zeros(len(npz["sensor_x"]), dtype=[("frame", "i4"), ("sx", "f8"),
                                                  ("sy", "f8"), ("sz", "f8"),
                                                  ("time", "f8")])
    for a, b in (("frame", "frame"), ("sx", "sensor_x"), ("sy", "sensor_y"),
                 ("sz", "sensor_z"), ("time", "gps_time")):
        rec[a] = npz[b]
    want = list(frames_from_points([rec]))
    for path, rtol in ((tmp_path / "old.laz", 0.0), (drive / "v.laz", 2.0**-24)):
        got = list(iter_frames(open_drive(path), chunk=5_000))
        assert [f.frame for f in got] == [f.frame for f in want] and len(want) > 1
        for g, w in zip(got, want):
            assert g.points.dtype == np.float64
            np.testing.assert_array_equal(g.times, w.times)
            np.testing.assert_allclose(g.points, w.points, rtol=rtol, atol=0)
    # The float32 file is smaller: 4 fields x 4 bytes less per point before LAZ.
    assert (tmp_path / "old.laz").stat().st_size > (drive / "v.laz").stat().st_size


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-512.0, 512.0, allow_nan=False), min_size=1, max_size=20))
def test_las_records_store_the_nearest_float32(values):
    """The LAS records hold, for any float64 sensor coordinate, the float32 nearest to it
    (no float32 neighbour is closer)."""
    head = laspy.LasHeader(point_format=6, version="1.4")
    head.add_extra_dims([laspy.ExtraBytesParams(name=n, type=np.dtype(t))
                         for n, _, t in LAS_EXTRA])
    v = np.asarray(values, dtype=np.float64)
    recs = np.zeros(len(v), dtype=[("sx", "f8")])
    recs["sx"] = v
    out = LasRecords(head).fill(np.zeros((len(v), 3)), records=recs,
                                copies={"sensor_x": "sx"})
    got = np.asarray(out["sensor_x"])
    assert got.dtype == np.float32
    err = np.abs(got.astype(np.float64) - v)
    for way in (np.inf, -np.inf):
        other = np.nextafter(got, np.float32(way)).astype(np.float64)
        assert (err <= np.abs(other - v)).all()
    assert (err <= 2.0**-24 * np.abs(v) + 2.0**-149).all()
