"""The ``tunnelsim`` command: version, info, one-line errors with exit status 2."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

from survey.cli.main import main


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("tunnelsim ") and out.strip().split()[1][0].isdigit()


def test_info_reports_threading(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    assert f"numba {numba.__version__}" in out
    layer = [line for line in out.splitlines() if line.startswith("numba threading layer")]
    assert layer and layer[0].split(": ")[1] in {"tbb", "omp", "workqueue"}
    assert f"numba threads: {numba.get_num_threads()} of" in out


def test_bad_command_is_one_line_exit_2(capsys):
    assert main(["frobnicate"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "invalid choice" in err


def test_console_script_installed():
    beside = Path(sys.executable).with_name("tunnelsim")
    exe = str(beside) if beside.exists() else shutil.which("tunnelsim")
    if exe is None:
        pytest.skip("tunnelsim console script not on PATH (package not installed)")
    res = subprocess.run([exe, "nope"], capture_output=True, text=True)
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr


def test_import_compiles_nothing():
    """The first import must not compile (or load) kernels: Numba compiles lazily."""
    code = ("import raytrace, survey.cli\n"
            "from raytrace._kernels import build, cubemap, traverse\n"
            "fs = [build.build_top, build._grow_pending, build.triangle_setup, "
            "traverse.closest_hit, traverse.any_hit, cubemap.closest_hit_view]\n"
            "print(sum(len(f.signatures) for f in fs))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert res.stdout.strip() == "0"


def test_tunnel_writes_mesh_metadata_and_epoch(tmp_path, capsys):
    out = tmp_path / "tbm.ply"
    ep = tmp_path / "tbm2.ply"
    assert main(["tunnel", "-o", str(out), "--preset", "tbm", "--edge-length", "0.5",
                 "--epoch2", str(ep), "--convergence", "40:60:5", "--origin",
                 "451000,5352000,600"]) == 0
    text = capsys.readouterr().out
    assert "wrote" in text and str(out) in text
    import json

    from survey.world.mesh import read_tunnel

    from tests.iofiles import mesh_fields as read_ply
    a, b = read_tunnel(out), read_tunnel(ep)
    assert json.loads(out.with_suffix(".json").read_text())["face_counts"]["cable"] > 0
    mid = np.isclose(a.vertex_chainage, 50.0)  # lining and attached features alike
    d = np.linalg.norm(b.vertices - a.vertices, axis=1)
    assert np.all(np.abs(d[mid & np.isfinite(a.vertex_param)] - 0.005) < 1e-9)
    assert np.all(d[np.isclose(a.vertex_chainage, 20.0)] == 0)
    assert a.vertices[:, 0].min() > 450_000
    np.testing.assert_allclose(read_ply(ep)["dx"], b.vertices[:, 0] - a.vertices[:, 0],
                               atol=1e-7)


@pytest.mark.parametrize("argv, match", [
    (["tunnel", "-o", "x.txt"], "ending in .ply"),
    (["tunnel", "-o", "no/such/dir/x.ply"], "existing output folder"),
    (["tunnel", "-o", "x.ply", "--convergence", "1:2"], "START:END:MM"),
    (["tunnel", "-o", "x.ply", "--edge-length", "0.0001"], "at most"),
    (["tunnel", "-o", "x.ply", "--preset", "moon"], "invalid choice"),
    (["tunnel"], "required"),
])
def test_tunnel_bad_input_is_one_line(argv, match, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and match in err
    assert not list(tmp_path.iterdir())


@pytest.fixture(scope="module")
def tbm(tbm_mesh):
    return tbm_mesh(0.3)


def test_sensors_lists_every_model(capsys):
    from sensors import list_sensors
    assert main(["sensors"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in list_sensors())


def test_scan_writes_a_station_with_the_mesh_reflectivity(tbm, tmp_path, capsys):
    import laspy

    from survey.world.mesh import read_tunnel
    out = tmp_path / "st.laz"
    assert main(["scan", "--mesh", str(tbm), "--at", "50,0,1.5", "--resolution", "preview",
                 "--ideal", "--fields", "full", "-o", str(out)]) == 0
    assert "points" in capsys.readouterr().out
    las = laspy.read(out)
    tun = read_tunnel(tbm)
    tri = np.asarray(las["triangle"])
    assert len(las.points) > 500_000 and tri.min() >= 0
    # intensity follows the label reflectivity: dark cable faces return weaker than
    # lining faces at similar range and incidence
    refl = tun.reflectivity[tri]
    rng = np.asarray(las["range"])
    inc = np.asarray(las["incidence"])
    band = (rng > 2.0) & (rng < 3.0) & (inc < 0.3)
    cable = band & (refl < 0.1)
    lining = band & (np.abs(refl - 0.4) < 1e-6)
    assert cable.sum() > 20 and lining.sum() > 20
    assert np.median(las.intensity[cable]) < np.median(las.intensity[lining])


def test_drive_along_the_centreline(tbm, tmp_path, capsys):
    import laspy
    out = tmp_path / "dr.laz"
    assert main(["drive", "--mesh", str(tbm), "--sensor", "velodyne_vlp16", "--along",
                 "centreline", "--speed", "2", "--duration", "0.3", "-o", str(out)]) == 0
    las = laspy.read(out)
    t = np.asarray(las.gps_time)
    assert len(t) > 10_000 and t.max() <= 0.3 + 1e-9
    assert set(np.unique(las.point_source_id)) <= {0, 1, 2, 3}       # frames at 10 Hz


@pytest.mark.parametrize("argv, match", [
    (["scan", "--mesh", "nope.ply", "--at", "1,2,3", "-o", "x.laz"], "does not exist"),
    (["scan", "--mesh", "TBM", "--at", "1,2", "-o", "x.laz"], "X,Y,Z"),
    (["scan", "--mesh", "TBM", "--at", "50,0,1.5", "--sensor", "nope", "-o", "x.laz"],
     "zf_imager_5016"),
    (["scan", "--mesh", "TBM", "--at", "50,0,1.5", "--resolution", "max", "-o", "x.laz"],
     "resolution"),
    (["scan", "--mesh", "TBM", "--at", "50,0,1.5", "--resolution", "preview", "-o", "x.txt"],
     "format"),
    (["drive", "--mesh", "TBM", "-o", "x.laz"], "--trajectory"),
    (["drive", "--mesh", "TBM", "--trajectory", "none.txt", "-o", "x.laz"], "does not exist"),
])
def test_scan_and_drive_bad_input(argv, match, tbm, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = [str(tbm) if a == "TBM" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and match in err
    assert not list(tmp_path.iterdir())


def _cp_files(tmp_path, n=8, seed=0):
    from survey.adjust.controlpoints import ControlPoints
    from survey.adjust.helmert import from_parameters
    rng = np.random.default_rng(seed)
    src = rng.uniform(-100, 100, (n, 3))
    h = from_parameters([451000.0, 5352000.0, 600.0], [10.0, -5.0, 300.0], 5.0)
    dst = h.apply(src) + rng.normal(0, 0.002, src.shape)
    ids = [f"P{i}" for i in range(n)]
    ControlPoints(ids, src).write(tmp_path / "src.csv")
    ControlPoints(ids, dst, np.full((n, 3), 0.002)).write(tmp_path / "dst.csv")
    return h, src, dst


def test_adjust_and_transform(tmp_path, capsys):
    import json

    import laspy
    h, src, dst = _cp_files(tmp_path)
    assert main(["adjust", str(tmp_path / "src.csv"), str(tmp_path / "dst.csv"), "--json",
                 str(tmp_path / "h.json"), "--report", str(tmp_path / "h.md")]) == 0
    out = capsys.readouterr().out
    assert "σ0 a posteriori" in out and "Baarda w" in out
    res = json.loads((tmp_path / "h.json").read_text())
    assert res["model"] == "7" and len(res["residuals"]) == 8
    np.testing.assert_allclose(res["rotation_arcsec"], [10.0, -5.0, 300.0], atol=20.0)
    # transform a small LAS cloud and compare with the fitted transform
    hdr = laspy.LasHeader(point_format=6, version="1.4")
    hdr.scales = [1e-4] * 3
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = src.T
    las.gps_time = np.arange(len(src), dtype=float)
    las.write(tmp_path / "c.las")
    assert main(["transform", str(tmp_path / "c.las"), "--helmert", str(tmp_path / "h.json"),
                 "-o", str(tmp_path / "c2.laz")]) == 0
    from survey.adjust.helmert import HelmertResult
    want = HelmertResult.from_dict(res).apply(np.stack([las.x, las.y, las.z], 1))
    back = laspy.read(tmp_path / "c2.laz")
    np.testing.assert_allclose(np.stack([back.x, back.y, back.z], 1), want, atol=1e-4)
    np.testing.assert_array_equal(back.gps_time, las.gps_time)


@pytest.mark.parametrize("argv, match", [
    (["adjust", "SRC", "missing.csv"], "does not exist"),
    (["adjust", "SRC", "SRC", "--model", "8"], "invalid choice"),
    (["transform", "c.las", "--helmert", "none.json", "-o", "x.laz"], "Helmert JSON"),
    (["correct", "--trajectory", "t.txt", "--cloud", "c.laz", "--control", "SRC",
      "--observed", "SRC", "-o", "x.laz"], "does not exist"),
])
def test_adjust_transform_correct_bad_input(argv, match, tmp_path, capsys, monkeypatch):
    _cp_files(tmp_path)
    monkeypatch.chdir(tmp_path)
    argv = [str(tmp_path / "src.csv") if a == "SRC" else a for a in argv]
    before = set(tmp_path.iterdir())
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and match in err
    assert set(tmp_path.iterdir()) == before


def test_correct_end_to_end(tmp_path, capsys):
    """A straight run with a known linear drift: the CLI's corrected cloud matches the
    truth and its report and plot are written."""
    import laspy
    from scipy.spatial.transform import Rotation

    from sensors import Trajectory
    from survey.adjust.controlpoints import ControlPoints
    t = np.linspace(0, 100, 201)
    true_pos = np.stack([t, 0 * t, 0 * t + 1.0], 1) + [451000.0, 5352000.0, 600.0]
    drift = np.stack([0 * t, 0.002 * t, 0.0005 * t], 1)          # 20 cm lateral at 100 s
    Trajectory(t, true_pos + drift, Rotation.identity(len(t))).write(tmp_path / "slam.txt")
    rng = np.random.default_rng(1)
    ids, g, m, tau = [], [], [], []
    for k, c in enumerate(np.arange(5.0, 100.0, 10.0)):
        for j, (dy, dz) in enumerate(((1.4, 1.0), (-1.4, 1.0), (0.0, 2.8))):
            ids.append(f"S{k}_{j}")
            p = np.array([451000.0 + c, 5352000.0 + dy, 600.0 + dz])
            g.append(p)
            m.append(p + drift[int(c * 2)])
            tau.append(c)
    ControlPoints(ids, np.array(g), np.full((len(g), 3), 0.0015)).write(tmp_path / "cp.csv")
    ControlPoints(ids, np.array(m), time=np.array(tau)).write(tmp_path / "cp_mls.csv")
    tt = rng.uniform(5, 95, 5000)
    truth = np.stack([451000.0 + tt, 5352000.0 + rng.uniform(-1.4, 1.4, 5000),
                      600.0 + rng.uniform(0, 2.8, 5000)], 1)
    mls = truth + np.stack([0 * tt, 0.002 * tt, 0.0005 * tt], 1)
    hdr = laspy.LasHeader(point_format=6, version="1.4")
    hdr.scales = [1e-4] * 3
    hdr.offsets = [451000.0, 5352000.0, 600.0]
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = mls.T
    las.gps_time = tt
    las.write(tmp_path / "mls.laz")
    assert main(["correct", "--trajectory", str(tmp_path / "slam.txt"), "--cloud",
                 str(tmp_path / "mls.laz"), "--control", str(tmp_path / "cp.csv"),
                 "--observed", str(tmp_path / "cp_mls.csv"), "-o",
                 str(tmp_path / "fixed.laz")]) == 0
    assert "check-point RMS" in capsys.readouterr().out
    back = laspy.read(tmp_path / "fixed.laz")
    err = np.stack([back.x, back.y, back.z], 1) - truth
    # Each section's pose also leans on its neighbours (weighted), which see a drift
    # 2 cm different: a few mm of bias at the walls for this drift, against 20 cm
    # removed (the model trades it for noise robustness, see survey.drift).
    assert np.abs(mls - truth).max() > 0.15
    assert np.abs(err).max() < 0.004
    assert (tmp_path / "fixed_report.md").is_file() and (tmp_path / "fixed_correction.png").is_file()
    fixed = Trajectory.read(tmp_path / "fixed_trajectory.txt")
    inner = (fixed.times > 5) & (fixed.times < 95)
    np.testing.assert_allclose(fixed.positions[inner], true_pos[inner], atol=0.004)


def test_preprocess_streams_a_cloud(tmp_path, capsys):
    import laspy

    from sensors.io.cloudmap import write_points_las
    from survey.clouds.preprocess import statistical_outliers, voxel_down_sample
    rng = np.random.default_rng(5)
    p = rng.normal(0, 2, (30_000, 3)) + [451_000.0, 5_352_000.0, 600.0]
    p[:20] += rng.normal(0, 40, (20, 3))
    write_points_las(tmp_path / "in.laz", p)
    q = laspy.read(tmp_path / "in.laz")
    stored = np.stack([q.x, q.y, q.z], 1)                  # 0.1 mm quantised input
    assert main(["preprocess", str(tmp_path / "in.laz"), "-o", str(tmp_path / "out.laz"),
                 "--voxel", "0.5", "--sor", "8,2.0"]) == 0
    assert "after outlier removal" in capsys.readouterr().out
    out = laspy.read(tmp_path / "out.laz")
    lo = np.asarray(q.header.mins)                        # the grid anchor the CLI uses
    from survey.clouds.preprocess import VoxelGrid
    g = VoxelGrid(0.5, lo)
    g.add(stored)
    want, counts = g.result()
    want = want[~statistical_outliers(want, k=8, std_ratio=2.0)]
    got = np.stack([out.x, out.y, out.z], 1)
    assert len(got) == len(want)
    np.testing.assert_allclose(got, want, atol=0.6e-4)
    assert np.asarray(out["voxel_count"]).sum() <= len(p)
    assert len(voxel_down_sample(stored, 0.5)) == len(counts)


def test_preprocess_bad_input(tmp_path, capsys):
    (tmp_path / "bad.xyz").write_text("1 2 x\n")
    assert main(["preprocess", str(tmp_path / "bad.xyz"), "-o", str(tmp_path / "o.laz"),
                 "--voxel", "0.1"]) == 2
    assert "numeric" in capsys.readouterr().err
    assert main(["preprocess", str(tmp_path / "none.laz"), "-o", str(tmp_path / "o.laz")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not (tmp_path / "o.laz").exists()


def test_mesh_reconstructs_a_generated_tunnel(tbm, tmp_path, capsys):
    """Points sampled on the tbm tunnel's lining (with 1 mm noise): the mesh command
    rebuilds it, with support per vertex, using the tunnel's own alignment."""
    from sensors.io.cloudmap import write_points_las
    from survey.world.mesh import LABEL
    from survey.world.mesh import read_tunnel
    from tests.iofiles import mesh_fields as read_ply
    tun = read_tunnel(tbm)
    rng = np.random.default_rng(0)
    lin = tun.faces[np.isin(tun.labels, [LABEL["lining"], LABEL["floor"]])]
    tri = tun.vertices[lin[rng.integers(0, len(lin), 200_000)]]
    w = rng.dirichlet([1, 1, 1], len(tri))
    pts = np.einsum("nk,nkj->nj", w, tri) + rng.normal(0, 0.001, (len(tri), 3))
    write_points_las(tmp_path / "c.laz", pts)
    assert main(["mesh", str(tmp_path / "c.laz"), "-o", str(tmp_path / "m.ply"), "--cell",
                 "0.5,4", "--tunnel-json", str(tbm.with_suffix(".json"))]) == 0
    assert "point-to-surface" in capsys.readouterr().out
    back = read_ply(tmp_path / "m.ply")
    assert back["support"].max() > 0 and len(back["faces"]) > 1000
    s, o, h = tun.alignment.to_local(back["vertices"])
    r = np.hypot(o, h - 2.5)                                  # tbm: circle r 2.5 m
    assert np.median(np.abs(r[back["support"] > 0] - 2.5)) < 0.01


def test_preprocess_segment_writes_classes(tbm, tmp_path, capsys):
    import laspy

    from sensors.io.cloudmap import write_points_las
    from survey.world.mesh import LABEL
    from survey.world.mesh import read_tunnel
    tun = read_tunnel(tbm)
    rng = np.random.default_rng(1)
    # Dense enough for the 0.25 m x 2 deg cells: 20 m of the tunnel (~500 points/m^2).
    window = np.flatnonzero((tun.vertex_chainage[tun.faces[:, 0]] > 40.0) &
                            (tun.vertex_chainage[tun.faces[:, 0]] < 60.0))
    pick = window[rng.integers(0, len(window), 150_000)]
    tri = tun.vertices[tun.faces[pick]]
    pts = np.einsum("nk,nkj->nj", rng.dirichlet([1, 1, 1], len(tri)), tri)
    write_points_las(tmp_path / "c.laz", pts)
    assert main(["preprocess", str(tmp_path / "c.laz"), "-o", str(tmp_path / "s.laz"),
                 "--segment", "--tunnel-json", str(tbm.with_suffix(".json"))]) == 0
    assert "classes:" in capsys.readouterr().out
    cls = np.asarray(laspy.read(tmp_path / "s.laz").classification)
    lab = tun.labels[pick]
    cable = np.isin(lab, [LABEL["cable"], LABEL["prism"]])
    # Points sampled all round the closed solids include their backs, a couple of cm
    # from the wall (within the 2 cm lining tolerance); those clearly in front count.
    s, o, h = tun.alignment.to_local(pts)
    front = cable & (tun.profile.distance(np.stack([o, h], 1)) > 0.04)
    assert np.mean(cls[front] == 65) > 0.95
    assert np.mean(np.isin(cls[~cable], [64, 2])) > 0.95


def test_mesh_budget_crop_and_coarse_las(tbm, tmp_path, capsys):
    import laspy

    from sensors.io.cloudmap import write_points_las
    from survey.world.mesh import LABEL
    from survey.world.mesh import read_tunnel
    from tests.iofiles import mesh_fields as read_ply
    tun = read_tunnel(tbm)
    rng = np.random.default_rng(2)
    lin = tun.faces[np.isin(tun.labels, [LABEL["lining"], LABEL["floor"]])]
    tri = tun.vertices[lin[rng.integers(0, len(lin), 100_000)]]
    pts = np.einsum("nk,nkj->nj", rng.dirichlet([1, 1, 1], len(tri)), tri)
    write_points_las(tmp_path / "c.laz", pts)
    js = str(tbm.with_suffix(".json"))
    assert main(["mesh", str(tmp_path / "c.laz"), "-o", str(tmp_path / "m.ply"), "--cell",
                 "0.5,4", "--tunnel-json", js, "--triangles", "5000", "--quiet"]) == 0
    assert len(read_ply(tmp_path / "m.ply")["faces"]) <= 5000
    assert main(["preprocess", str(tmp_path / "c.laz"), "-o", str(tmp_path / "p.laz"),
                 "--crop", "20,30", "--tunnel-json", js, "--quiet"]) == 0
    out = laspy.read(tmp_path / "p.laz")
    s, _, _ = tun.alignment.to_local(np.stack([out.x, out.y, out.z], 1))
    assert len(s) > 1000 and s.min() >= 20 - 1e-3 and s.max() <= 30 + 1e-3
    # A LAS written with a 10 cm scale is refused with the reason.
    hdr = laspy.LasHeader(point_format=6, version="1.4")
    hdr.scales = [0.1, 0.1, 0.1]
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = pts[:100].T
    las.write(tmp_path / "coarse.las")
    assert main(["preprocess", str(tmp_path / "coarse.las"), "-o", str(tmp_path / "x.laz")]) == 2
    err = capsys.readouterr().err
    assert "too coarse" in err and len(err.strip().splitlines()) == 1


def test_mesh_detail_layer_keeps_the_cable(tbm, tmp_path, capsys):
    import trimesh

    from sensors.io.cloudmap import write_points_las
    from survey.world.mesh import read_tunnel
    from tests.iofiles import mesh_fields as read_ply
    tun = read_tunnel(tbm)
    rng = np.random.default_rng(3)
    window = np.flatnonzero((tun.vertex_chainage[tun.faces[:, 0]] > 30.0) &
                            (tun.vertex_chainage[tun.faces[:, 0]] < 50.0))
    tri = tun.vertices[tun.faces[window[rng.integers(0, len(window), 200_000)]]]
    pts = np.einsum("nk,nkj->nj", rng.dirichlet([1, 1, 1], len(tri)), tri)
    write_points_las(tmp_path / "c.laz", pts)
    assert main(["mesh", str(tmp_path / "c.laz"), "-o", str(tmp_path / "m.ply"),
                 "--tunnel-json", str(tbm.with_suffix(".json")), "--detail"]) == 0
    assert "detail layer" in capsys.readouterr().out
    ply = read_ply(tmp_path / "m.ply")
    detail = ply["support"] == -1
    assert detail.sum() > 0
    s, o, h = tun.alignment.to_local(ply["vertices"][detail])
    t = tun.profile.t_at_height("left", 3.0)                  # tbm cable: 3 m, r 3 cm
    c = tun.profile.points(t) - tun.profile.normals(t) * 0.06
    near = np.hypot(o - c[0], h - c[1]) < 0.06
    assert near.mean() > 0.5
    tube = detail[ply["faces"]].all(axis=1)
    mesh = trimesh.Trimesh(ply["vertices"], ply["faces"][tube], process=False)
    assert tube.sum() > 0 and mesh.is_watertight and mesh.is_winding_consistent
