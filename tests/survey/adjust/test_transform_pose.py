"""``tunnelsim transform`` moves a station's recorded pose with its points and takes
E57 (issue 21).

References are independent of the code under test: the expected pose is built here
with scipy's ``Rotation`` from the Helmert's matrix, translation and scale; LAS files
are read with laspy, E57 files with pye57 (its own pose application, ``read_scan``).
"""

from __future__ import annotations

import json

import laspy
import numpy as np
import pye57
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import simulate_station
from sensors.io.e57 import write_e57_scan
from survey.adjust.helmert import from_parameters
from survey.cli.main import main
from sensors.io.cloudmap import map_cloud

T_M = np.array([2_600_120.5, 1_199_960.25, 503.0])
R_ARCSEC = np.array([40.0, -25.0, 5.0 * 3600.0])     # 5 degrees about z: order matters
S_PPM = 25.0
POSITION = np.array([12.0, 0.3, 1.4])
ATTITUDE = Rotation.from_euler("zyx", [35.0, 2.0, -1.5], degrees=True)


def _vlr_info(path):
    head = laspy.read(path).header
    vs = [v for v in head.vlrs if v.user_id == "tunnelsim" and v.record_id == 1]
    assert len(vs) == 1
    return json.loads(bytes(vs[0].record_data).decode())


def _las_xyz(path):
    las = laspy.read(path)
    return np.stack([las.x, las.y, las.z], 1), las


def _expected_pose(res, p, q, inverse=False):
    """The station pose in the Helmert's target (source) system, by hand."""
    r_h = Rotation.from_matrix(res.rotation_matrix)
    sc = 1.0 + res.scale_ppm * 1e-6
    if inverse:
        return r_h.inv().apply(np.asarray(p) - res.translation_m) / sc, \
            r_h.inv() * Rotation.from_quat(q)
    return res.translation_m + sc * r_h.apply(p), r_h * Rotation.from_quat(q)


def _same_rotation(a, b, tol=1e-12):
    return (a.inv() * b).magnitude() < tol


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    """A tilted TLS station in a short tube, as LAZ (compact fields) and E57, and the
    Helmert JSON (t, 5 degree rotation, 25 ppm)."""
    d = tmp_path_factory.mktemp("pose")
    v, f = tunnel_tube(4_000, length_m=30.0, seed=3)
    run = simulate_station(Scene(v, f), "zf_imager_5016", POSITION, attitude=ATTITUDE,
                           step_rad=np.deg2rad(1.5), seed=4)
    run.write(d / "s.laz", fields="compact")
    run.write(d / "s.e57")
    run.write(d / "s.ply")
    res = from_parameters(T_M, R_ARCSEC, S_PPM)
    (d / "h.json").write_text(json.dumps(res.to_dict()))
    rigid = from_parameters(T_M, R_ARCSEC, 0.0)
    (d / "rigid.json").write_text(json.dumps(rigid.to_dict()))
    return d, res, rigid


def _transform(*args):
    assert main(["transform", *map(str, args), "--quiet"]) == 0


def test_laz_pose_follows_the_points(station, tmp_path):
    d, res, _ = station
    out = tmp_path / "t.laz"
    _transform("--helmert", d / "h.json", d / "s.laz", "-o", out)
    info0, info = _vlr_info(d / "s.laz"), _vlr_info(out)
    assert np.allclose(info0["station_position"], POSITION)
    p, r = _expected_pose(res, info0["station_position"],
                          info0["station_quaternion_xyzw"])
    assert np.allclose(info["station_position"], p, rtol=0, atol=1e-9)
    assert _same_rotation(Rotation.from_quat(info["station_quaternion_xyzw"]), r)
    assert info["sensor"] == info0["sensor"] and info["seed"] == info0["seed"]
    # Output points = new pose applied to the unchanged sensor-frame points, x (1 + s).
    xyz0, las0 = _las_xyz(d / "s.laz")
    xyz, las = _las_xyz(out)
    local = ATTITUDE.inv().apply(xyz0 - POSITION)
    want = p + (1.0 + S_PPM * 1e-6) * r.apply(local)
    assert len(xyz) > 5_000
    assert np.abs(xyz - want).max() <= 1e-4            # the LAS scale (0.1 mm)
    assert np.array_equal(las.channel, las0.channel)
    # --inverse returns the original pose.
    back = tmp_path / "b.laz"
    _transform("--helmert", d / "h.json", out, "-o", back, "--inverse")
    info_b = _vlr_info(back)
    assert np.allclose(info_b["station_position"], POSITION, rtol=0, atol=1e-9)
    assert _same_rotation(Rotation.from_quat(info_b["station_quaternion_xyzw"]), ATTITUDE)


def test_ply_comment_pose_is_transformed(station, tmp_path):
    from sensors.io.ply import read_ply_header

    d, res, _ = station
    _transform("--helmert", d / "h.json", d / "s.ply", "-o", tmp_path / "t.ply")
    tag = "comment tunnelsim {"
    info = [json.loads(c[len(tag) - 1:]) for c in read_ply_header(tmp_path / "t.ply").comments
            if c.startswith(tag)]
    p, r = _expected_pose(res, POSITION, ATTITUDE.as_quat())
    assert len(info) == 1 and np.allclose(info[0]["station_position"], p, rtol=0, atol=1e-9)
    assert _same_rotation(Rotation.from_quat(info[0]["station_quaternion_xyzw"]), r)


def test_a_drives_mount_stays_and_a_file_without_the_record_is_kept(station, tmp_path):
    _, _, rigid = station
    h = tmp_path / "h.json"
    h.write_text(json.dumps(rigid.to_dict()))
    mount = {"sensor": "velodyne_vlp16", "seed": 1, "mount_lever_arm_m": [0.1, 0, 1.2],
             "mount_boresight_xyzw": [0.0, 0.0, 0.3826834, 0.9238795]}
    xyz = np.random.default_rng(0).uniform(-5, 5, (200, 3))
    for name, vlrs in (("drive.las", [laspy.VLR("tunnelsim", 1, "info",
                                                json.dumps(mount).encode())]),
                       ("plain.las", [])):
        head = laspy.LasHeader(point_format=6, version="1.4")
        head.scales, head.offsets = np.full(3, 1e-4), np.zeros(3)
        head.vlrs.extend(vlrs)
        las = laspy.LasData(head)
        las.x, las.y, las.z = xyz.T
        las.write(tmp_path / name)
        _transform("--helmert", h, tmp_path / name, "-o", tmp_path / ("t_" + name))
        got, _ = _las_xyz(tmp_path / ("t_" + name))
        assert np.abs(got - rigid.apply(_las_xyz(tmp_path / name)[0])).max() <= 1e-4
    assert _vlr_info(tmp_path / "t_drive.las") == mount
    assert not [v for v in laspy.read(tmp_path / "t_plain.las").header.vlrs
                if v.user_id == "tunnelsim"]


def _e57(path):
    e = pye57.E57(str(path))
    try:
        head = e.get_header(0)
        q_wxyz, t = np.asarray(head.rotation), np.asarray(head.translation)
        raw = e.read_scan_raw(0)
        world = e.read_scan(0, ignore_missing_fields=True)     # pose applied
        meta = e.root["coordinateMetadata"].value()
    finally:
        e.close()
    return t, Rotation.from_quat(np.r_[q_wxyz[1:], q_wxyz[0]]), raw, world, meta


def test_e57_pose_is_transformed_and_world_points_follow(station, tmp_path):
    d, res, _ = station
    out = tmp_path / "t.e57"
    _transform("--helmert", d / "h.json", d / "s.e57", "-o", out, "--crs", "EPSG:2056")
    t0, r0, raw0, world0, meta0 = _e57(d / "s.e57")
    t, r, raw, world, meta = _e57(out)
    assert np.allclose(t0, POSITION) and _same_rotation(r0, ATTITUDE, 1e-6)
    p_want, r_want = _expected_pose(res, t0, r0.as_quat())
    assert np.allclose(t, p_want, rtol=0, atol=1e-9)
    assert _same_rotation(r, r_want)
    xyz0 = np.stack([world0[k] for k in ("cartesianX", "cartesianY", "cartesianZ")], 1)
    xyz = np.stack([world[k] for k in ("cartesianX", "cartesianY", "cartesianZ")], 1)
    assert len(xyz) > 5_000
    assert np.abs(xyz - res.apply(xyz0)).max() <= 1e-4
    for k in ("intensity", "rowIndex", "columnIndex"):
        assert np.array_equal(raw[k], raw0[k]), k
    from pyproj import CRS

    assert meta0 == "" and CRS.from_wkt(meta).equals(CRS("EPSG:2056"))
    # --inverse: the original pose and scan-frame points (E57 stores them as float32).
    back = tmp_path / "b.e57"
    _transform("--helmert", d / "h.json", out, "-o", back, "--inverse")
    tb, rb, rawb, _, _ = _e57(back)
    assert np.allclose(tb, t0, rtol=0, atol=1e-9) and _same_rotation(rb, r0)
    for k in ("cartesianX", "cartesianY", "cartesianZ"):
        assert np.abs(rawb[k] - raw0[k]).max() <= 1e-5


def test_e57_rigid_transform_keeps_the_scan_frame_points(station, tmp_path):
    d, _, rigid = station
    out = tmp_path / "r.e57"
    _transform("--helmert", d / "rigid.json", d / "s.e57", "-o", out)
    _, _, raw0, _, _ = _e57(d / "s.e57")
    _, r, raw, _, _ = _e57(out)
    for k in ("cartesianX", "cartesianY", "cartesianZ"):
        assert np.array_equal(raw[k], raw0[k]), k
    assert _same_rotation(r, Rotation.from_matrix(rigid.rotation_matrix) * ATTITUDE, 1e-6)


def test_e57_needs_an_e57_output(station, tmp_path, capsys):
    d, _, _ = station
    assert main(["transform", "--helmert", str(d / "h.json"), str(d / "s.e57"), "-o",
                 str(tmp_path / "x.laz")]) == 2
    assert "Expected a .e57 output" in capsys.readouterr().err
    assert not (tmp_path / "x.laz").exists()


@settings(max_examples=15, deadline=None)
@given(t=st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3),
       angles=st.lists(st.floats(-np.pi, np.pi), min_size=3, max_size=3),
       scale=st.floats(-500.0, 500.0),
       pose_angles=st.lists(st.floats(-np.pi, np.pi), min_size=3, max_size=3))
def test_e57_world_points_are_fns_for_any_pose(tmp_path_factory, t, angles, scale,
                                               pose_angles):
    """Whatever pose the output is given, its world points are ``fn``'s: the scan-frame
    points absorb the difference."""
    d = tmp_path_factory.mktemp("prop")
    rng = np.random.default_rng(1)
    local = rng.uniform(-20, 20, (64, 3))
    r0 = Rotation.from_rotvec([0.1, -0.2, 0.7])
    write_e57_scan(d / "a.e57", local, rotation_xyzw=r0.as_quat(),
                   translation=np.array([5.0, 6.0, 7.0]), name="a")
    rot, sc = Rotation.from_euler("xyz", angles), 1.0 + scale * 1e-6

    def fn(xyz, _t):
        return np.asarray(t) + sc * rot.apply(xyz)

    new_rot = Rotation.from_euler("xyz", pose_angles)
    map_cloud(d / "a.e57", d / "b.e57", fn,
              pose=lambda p, q: (p + 1.0, (new_rot * Rotation.from_quat(q)).as_quat()))
    _, _, _, w0, _ = _e57(d / "a.e57")
    _, _, _, w1, _ = _e57(d / "b.e57")
    x0 = np.stack([w0[k] for k in ("cartesianX", "cartesianY", "cartesianZ")], 1)
    x1 = np.stack([w1[k] for k in ("cartesianX", "cartesianY", "cartesianZ")], 1)
    assert np.abs(x1 - fn(x0, None)).max() <= 1e-4     # float32 scan-frame storage
