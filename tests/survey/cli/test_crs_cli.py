"""Coordinate reference systems end to end (issue 21), on what a user gets: a tunnel at
EPSG:2056 whose scans state it, ``compare`` and ``adjust`` refusing inputs in two CRSs
(exit 2, one line naming both), ``transform`` stating the target CRS, rewrites keeping
or replacing the input's, the Gazebo export naming it.

References are independent of ``sensors.io.crs``: pyproj builds and compares the expected
CRSs (``CRS.equals``), laspy reads LAS headers (``parse_crs``), pye57 the E57 root's
``coordinateMetadata``, and sidecars and JSON files are read as plain text.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import laspy
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sensors import simulate_station
from sensors.io.meshes import load_mesh
from survey.adjust.controlpoints import ControlPoints
from survey.cli.main import main
from sensors.io.cloudmap import KEEP_CRS, map_cloud
from sensors.io.cloudread import cloud_crs, cloud_crs_text
from survey.world.alignment import Alignment
from sensors.io.tunnel_json import read_meta

pyproj = pytest.importorskip("pyproj", reason="CRS handling needs pyproj (pip install "
                              "'tunnelsim[crs]'); every test here uses it")
CRS = pyproj.CRS

LV95 = CRS("EPSG:2056")
UTM32 = CRS("EPSG:32632")
ORIGIN = "2600000,1200000,500"


def _one_error(capsys, *words) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tunnelsim: error: "), err
    for w in words:
        assert w in err[0], (w, err[0])
    return err[0]


def _las_crs(path):
    return laspy.read(path).header.parse_crs()


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The acceptance chain: ``tunnel --preset tbm --origin 2600000,1200000,500 --crs
    EPSG:2056`` (and a second epoch), then a station at chainage 50 m scanned through
    the library with the JSON's ``crs`` into LAZ, E57 and PLY (a 1 degree step)."""
    d = tmp_path_factory.mktemp("lv95")
    assert main(["tunnel", "--preset", "tbm", "--origin", ORIGIN, "--crs", "EPSG:2056",
                 "--edge-length", "0.5", "-o", str(d / "t.ply"), "--epoch2",
                 str(d / "t2.ply"), "--quiet"]) == 0
    meta = read_meta(d / "t.json")
    scene, refl = load_mesh(d / "t.ply")
    at = Alignment.from_dict(meta["alignment"]).to_world(np.array([50.0]), 0.0, 1.5)[0]
    run = simulate_station(scene, "zf_imager_5016", at, step_rad=np.deg2rad(1.0), seed=2,
                           reflectivity=refl)      # ~30k points: the CRS is the point
    for suffix in ("laz", "e57", "ply"):
        run.write(d / f"s.{suffix}", crs=meta["crs"])
    return d


# ---------------------------------------------------------------------------- acceptance
def test_a_tunnel_at_epsg_2056_is_scanned_into_files_that_state_it(site):
    import pye57

    meta = json.loads((site / "t.json").read_text())
    assert CRS.from_wkt(meta["crs"]).equals(LV95)
    assert meta["crs_name"] == "EPSG:2056 (CH1903+ / LV95)"
    assert CRS.from_wkt(json.loads((site / "t2.json").read_text())["crs"]).equals(LV95)
    las = laspy.read(site / "s.laz")
    assert las.header.parse_crs().equals(LV95) and las.header.global_encoding.wkt
    assert abs(float(np.mean(las.x)) - 2_600_050.0) < 10.0     # LV95 coordinates
    e57 = pye57.E57(str(site / "s.e57"))
    try:
        assert CRS.from_wkt(e57.root["coordinateMetadata"].value()).equals(LV95)
    finally:
        e57.close()
    assert CRS.from_wkt((site / "s.ply.prj").read_text()).equals(LV95)
    for name in ("s.laz", "s.e57", "s.ply", "t.ply"):
        assert cloud_crs(site / name).equals(LV95), name


def test_compare_refuses_clouds_in_two_crss_naming_both(site, tmp_path, capsys):
    utm = tmp_path / "utm.laz"
    map_cloud(site / "s.laz", utm, lambda xyz, t: xyz, crs="EPSG:32632")
    assert _las_crs(utm).equals(UTM32)
    out = tmp_path / "cmp"
    assert main(["compare", str(site / "s.laz"), str(utm), "-o", str(out)]) == 2
    _one_error(capsys, f"'{site / 's.laz'}' in EPSG:2056 (CH1903+ / LV95)",
               f"'{utm}' in EPSG:32632 (WGS 84 / UTM zone 32N)", "--allow-crs-mismatch")
    assert not out.exists()
    # Meant (the same coordinates under a wrong label): compared.
    assert main(["compare", str(site / "s.laz"), str(utm), "-o", str(out), "--quiet",
                 "--allow-crs-mismatch"]) == 0


def test_compare_keeps_the_crs_in_its_outputs(site, tmp_path):
    import shutil

    for a, b in (("s.e57", "a.e57"), ("s.ply", "b.ply"), ("s.ply.prj", "b.ply.prj"),
                 ("s.laz", "c.laz")):
        shutil.copy(site / a, tmp_path / b)
    out = tmp_path / "cmp"
    # E57 and PLY (rewritten from points) and LAZ (annotated) against the tunnel mesh,
    # whose CRS is its JSON's.
    assert main(["compare", *(str(tmp_path / n) for n in ("a.e57", "b.ply", "c.laz")),
                 str(site / "t.ply"), "-o", str(out), "--quiet", "--max-dist",
                 "0.5"]) == 0
    for name in ("a", "b", "c"):
        assert _las_crs(out / f"{name}_distance.laz").equals(LV95), name


def test_a_cloud_stating_no_crs_is_not_refused(site, tmp_path, capsys):
    bare = tmp_path / "bare.laz"
    map_cloud(site / "s.laz", bare, lambda xyz, t: xyz, crs=None)
    assert _las_crs(bare) is None and cloud_crs_text(bare) is None
    assert main(["compare", str(bare), str(site / "t.ply"), "-o", str(tmp_path / "c"),
                 "--quiet"]) == 0


# ---------------------------------------------------------------------------- tunnel
def test_a_bad_crs_is_one_line_and_writes_nothing(tmp_path, capsys):
    for bad, words in (("LV95", "got 'LV95'"), ("2056", "write EPSG:2056"),
                       ("EPSG:4326", "axes in metres"), ("EPSG:0", "which it refuses")):
        assert main(["tunnel", "--preset", "tbm", "--origin", ORIGIN, "--crs", bad,
                     "-o", str(tmp_path / "t.ply")]) == 2
        _one_error(capsys, "Expected --crs", words)
        assert list(tmp_path.iterdir()) == []


def test_a_crs_without_an_origin_warns(tmp_path, capsys):
    assert main(["tunnel", "--preset", "tbm", "--crs", "EPSG:2056", "--edge-length", "1",
                 "-o", str(tmp_path / "t.ply"), "--quiet"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [err[0]] and err[0].startswith(
        "tunnelsim: warning: The default origin at (0.000, 0.000, 0.000) is outside the "
        "area of use of EPSG:2056 (CH1903+ / LV95)")
    assert "--origin E,N,H" in err[0]


# ---------------------------------------------------------------------------- adjust
def _control(tmp_path, *, source_crs=None, target_crs=None):
    """Eight control points along a 100 m tunnel: local (source) and LV95 (target, a
    30 deg rotation and the site's origin, 1 mm noise), written as CSVs that state
    their CRS in a ``# crs:`` line."""
    rng = np.random.default_rng(4)
    local = np.c_[np.linspace(5, 95, 8), np.tile([-2.2, 2.2], 4),
                  np.tile([1.0, 3.5, 2.0, 4.2], 2)]
    rot = Rotation.from_euler("z", 30.0, degrees=True)
    grid = rot.apply(local) + [2_600_000.0, 1_200_000.0, 500.0] + \
        rng.normal(0.0, 0.001, local.shape)
    ids = [f"CP{i:02d}" for i in range(1, 9)]
    paths = []
    for name, xyz, crs in (("local.csv", local, source_crs), ("grid.csv", grid, target_crs)):
        p = ControlPoints(ids, xyz).write(tmp_path / name)
        if crs is not None:
            p.write_text(f"# crs: {crs}\n" + p.read_text())
        paths.append(p)
    return paths


def test_adjust_refuses_control_points_in_two_crss(tmp_path, capsys):
    src, dst = _control(tmp_path, source_crs="EPSG:32632", target_crs="EPSG:2056")
    assert main(["adjust", str(src), str(dst), "--quiet"]) == 2
    _one_error(capsys, f"'{src}' in EPSG:32632 (WGS 84 / UTM zone 32N)",
               f"'{dst}' in EPSG:2056 (CH1903+ / LV95)", "datum transformation",
               "--allow-crs-mismatch")
    out = tmp_path / "h.json"
    assert main(["adjust", str(src), str(dst), "--quiet", "--allow-crs-mismatch",
                 "--json", str(out)]) == 0
    d = json.loads(out.read_text())
    assert CRS.from_wkt(d["source_crs"]).equals(UTM32)
    assert CRS.from_wkt(d["target_crs"]).equals(LV95)


def test_adjust_records_the_crss_and_the_report_names_them(tmp_path, capsys):
    src, dst = _control(tmp_path, target_crs="EPSG:2056")
    out, rep = tmp_path / "h.json", tmp_path / "h.md"
    assert main(["adjust", str(src), str(dst), "--quiet", "--json", str(out),
                 "--report", str(rep)]) == 0
    d = json.loads(out.read_text())
    assert d["source_crs"] is None and CRS.from_wkt(d["target_crs"]).equals(LV95)
    assert "source none stated, target EPSG:2056 (CH1903+ / LV95)" in rep.read_text()


# ---------------------------------------------------------------------------- transform
@pytest.fixture()
def helmert(tmp_path):
    """(JSON path) of a local -> EPSG:2056 adjustment."""
    src, dst = _control(tmp_path, target_crs="EPSG:2056")
    out = tmp_path / "h.json"
    assert main(["adjust", str(src), str(dst), "--quiet", "--json", str(out)]) == 0
    return out


def _local_cloud(site, tmp_path, crs=None):
    """The station's cloud moved back into the local frame (the inverse of the control
    points' transform, near enough), stating ``crs``."""
    rot = Rotation.from_euler("z", 30.0, degrees=True)
    path = tmp_path / "local.laz"
    map_cloud(site / "s.laz", path,
              lambda xyz, t: rot.inv().apply(xyz - [2_600_000.0, 1_200_000.0, 500.0]),
              crs=crs)
    return path


def test_transform_states_the_target_crs(site, tmp_path, helmert, capsys):
    cloud = _local_cloud(site, tmp_path)
    out = tmp_path / "grid.laz"
    assert main(["transform", "--helmert", str(helmert), str(cloud), "-o", str(out)]) == 0
    assert "(EPSG:2056 (CH1903+ / LV95))" in capsys.readouterr().out
    assert _las_crs(out).equals(LV95)
    # --crs agreeing with the recorded target is fine; another is refused.
    assert main(["transform", "--helmert", str(helmert), str(cloud), "-o", str(out),
                 "--crs", LV95.to_wkt("WKT1_GDAL"), "--quiet"]) == 0
    assert main(["transform", "--helmert", str(helmert), str(cloud), "-o",
                 str(tmp_path / "x.laz"), "--crs", "EPSG:32632"]) == 2
    _one_error(capsys, "Expected --crs to agree with the target CRS recorded",
               "EPSG:32632", "EPSG:2056")
    assert not (tmp_path / "x.laz").exists()


def test_transform_drops_a_crs_that_no_longer_holds(site, tmp_path, helmert, capsys):
    # Inverse: back into the local frame, which states no CRS: the LV95 label goes.
    out = tmp_path / "back.laz"
    assert main(["transform", "--helmert", str(helmert), str(site / "s.laz"), "-o",
                 str(out), "--inverse", "--quiet"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tunnelsim: warning: ") and \
        "EPSG:2056 (CH1903+ / LV95) does not hold after the transform" in err[0]
    head = laspy.read(out).header
    assert head.parse_crs() is None and not head.global_encoding.wkt


def test_transform_refuses_a_cloud_in_another_crs_than_its_source(site, tmp_path,
                                                                   capsys):
    src, dst = _control(tmp_path, source_crs="EPSG:32632", target_crs="EPSG:2056")
    h = tmp_path / "h.json"
    assert main(["adjust", str(src), str(dst), "--quiet", "--allow-crs-mismatch",
                 "--json", str(h)]) == 0
    cloud = _local_cloud(site, tmp_path, crs="EPSG:2056")
    assert main(["transform", "--helmert", str(h), str(cloud), "-o",
                 str(tmp_path / "x.laz")]) == 2
    _one_error(capsys, f"'{cloud}' in EPSG:2056", "(source)' in EPSG:32632",
               "estimated for other coordinates")
    cloud = _local_cloud(site, tmp_path, crs="EPSG:32632")       # the right one
    assert main(["transform", "--helmert", str(h), str(cloud), "-o",
                 str(tmp_path / "y.laz"), "--quiet"]) == 0
    assert _las_crs(tmp_path / "y.laz").equals(LV95)


def test_transform_crs_states_a_ply_outputs_crs_in_its_sidecar(site, tmp_path, capsys):
    src, dst = _control(tmp_path)                  # no CRS anywhere
    h = tmp_path / "h.json"
    assert main(["adjust", str(src), str(dst), "--quiet", "--json", str(h)]) == 0
    out = tmp_path / "g.ply"
    assert main(["transform", "--helmert", str(h), str(site / "s.ply"), "-o", str(out),
                 "--crs", "EPSG:2056", "--quiet"]) == 0
    assert CRS.from_wkt((tmp_path / "g.ply.prj").read_text()).equals(LV95)
    assert main(["transform", "--helmert", str(h), str(site / "s.ply"), "-o", str(out),
                 "--crs", "LV95"]) == 2
    _one_error(capsys, "Expected --crs as EPSG:n")


# ---------------------------------------------------------------------------- rewrites
@pytest.mark.parametrize("suffix", ["laz", "ply"])
def test_rewrites_keep_replace_or_drop_the_crs(site, tmp_path, suffix):
    src, dst = site / f"s.{suffix}", tmp_path / f"r.{suffix}"

    def same(xyz, t):
        return xyz

    for crs, want in ((KEEP_CRS, LV95), ("EPSG:32632", UTM32), (None, None)):
        map_cloud(src, dst, same, crs=crs)
        got = cloud_crs(dst)
        assert (got is None) if want is None else got.equals(want), (crs, got)
    if suffix == "laz":
        map_cloud(src, dst, same)
        vlrs = [(v.user_id, v.record_id) for v in laspy.read(dst).header.vlrs]
        assert vlrs.count(("LASF_Projection", 2112)) == 1 and ("tunnelsim", 1) in vlrs


def test_text_clouds_state_their_crs_in_a_comment_or_a_sidecar(tmp_path):
    xyz = tmp_path / "p.xyz"
    xyz.write_text("# crs: EPSG:2056\n2600000 1200000 500\n")
    assert cloud_crs(xyz).equals(LV95)
    npz = tmp_path / "p.npz"
    np.savez(npz, x=[0.0], y=[0.0], z=[0.0])
    assert cloud_crs(npz) is None
    (tmp_path / "p.npz.prj").write_text(UTM32.to_wkt())
    assert cloud_crs(npz).equals(UTM32)


# ---------------------------------------------------------------------------- gazebo
def test_gazebo_records_the_crs_and_the_local_origin(site, tmp_path, capsys):
    out = tmp_path / "world"
    assert main(["gazebo", "--mesh", str(site / "t.ply"), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "m in EPSG:2056 (CH1903+ / LV95)" in text
    model = ET.parse(out / "models" / "tunnel" / "model.sdf").getroot()
    ns = "{https://github.com/tunnelsim}"
    crs = model.find(f"model/{ns}crs")
    assert crs is not None and crs.get("name") == "EPSG:2056 (CH1903+ / LV95)"
    assert CRS.from_wkt(crs.text).equals(LV95)
    origin = [float(v) for v in model.find(f"model/{ns}origin").text.split()]
    assert origin[0] == pytest.approx(2_600_000.0, abs=10.0)
    assert "in EPSG:2056 (CH1903+ / LV95)" in (out / "README.txt").read_text()
    assert "in EPSG:2056" in (out / "models" / "tunnel" / "model.config").read_text()
    ET.parse(out / "world.sdf")                     # still well-formed XML


# ---------------------------------------------------------------------------- correct
def test_correct_gives_the_cloud_the_control_points_crs(tmp_path):
    """A run in a slightly shifted frame, corrected with control points that state
    EPSG:2056: the corrected cloud states it (the input stated none)."""
    from sensors import Trajectory
    from sensors.io.las import write_las

    base = np.array([2_600_000.0, 1_200_000.0, 500.0])
    t = np.linspace(0.0, 10.0, 101)
    pos = base + np.c_[5.0 * t, 0 * t, 0 * t]
    Trajectory(t, pos, Rotation.identity(len(t))).write(tmp_path / "traj.txt")
    tp = np.linspace(0.0, 10.0, 2001)
    cloud = base + np.c_[5.0 * tp, np.sin(tp), np.cos(tp) + 2.0]
    write_las(tmp_path / "run.laz", cloud, fields={"gps_time": tp})
    ids = [f"P{i}" for i in range(6)]
    tc = np.linspace(1.0, 9.0, 6)
    seen = base + np.c_[5.0 * tc, np.tile([-2.0, 2.0], 3), np.tile([1.0, 4.0], 3)]
    ControlPoints(ids, seen, time=tc).write(tmp_path / "seen.csv")
    world = ControlPoints(ids, seen + [0.02, -0.01, 0.0]).write(tmp_path / "world.csv")
    world.write_text("# crs: EPSG:2056\n" + world.read_text())
    out = tmp_path / "fixed.laz"
    assert main(["correct", "--trajectory", str(tmp_path / "traj.txt"), "--cloud",
                 str(tmp_path / "run.laz"), "--control", str(world), "--observed",
                 str(tmp_path / "seen.csv"), "--model", "global", "-o", str(out),
                 "--quiet"]) == 0
    assert _las_crs(tmp_path / "run.laz") is None
    assert _las_crs(out).equals(LV95)


def test_scan_and_drive_state_the_mesh_crs(site, tmp_path, capsys):
    """The commands a user runs: `scan` on the EPSG:2056 tunnel writes a LAZ whose
    header laspy reads as EPSG:2056 (taken from the tunnel JSON); a --crs against the
    mesh's own is refused in one line naming both; `drive --slam-drift` states the
    CRS in the world control points and none in the drifted cloud (it lies in the SLAM
    frame, which `correct` repairs)."""
    d = site
    out = tmp_path / "s.laz"
    assert main(["scan", "--mesh", str(d / "t.ply"), "--chainage", "50", "--step-deg", "2",
                 "-o", str(out), "--quiet"]) == 0
    assert LV95.equals(_las_crs(out))
    assert main(["scan", "--mesh", str(d / "t.ply"), "--chainage", "50", "--step-deg", "2",
                 "--crs", "EPSG:32632", "-o", str(tmp_path / "u.laz"), "--quiet"]) == 2
    _one_error(capsys, "EPSG:32632", "EPSG:2056")
    assert not (tmp_path / "u.laz").exists()
    assert main(["drive", "--mesh", str(d / "t.ply"), "--sensor", "velodyne_vlp16", "--along",
                 "centreline", "--speed", "20", "--slam-drift", "-o", str(tmp_path / "m.laz"),
                 "--quiet"]) == 0
    first = (tmp_path / "m_cp_world.csv").read_text().splitlines()[0]
    assert first.startswith("# crs:") and LV95.equals(CRS(first.split(":", 1)[1].strip()))
    assert _las_crs(tmp_path / "m.laz") is None
