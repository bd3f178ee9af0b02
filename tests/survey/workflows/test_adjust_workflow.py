"""Issue 32: adjust, transform, correct, slam and detect as library calls
(``survey.workflows.adjust``, ``.slam``, ``.detect``).

Notebook-style: the command (``survey.cli.main.main`` in-process) and the library
function run on the same small inputs into two folders and must write the same files,
byte for byte. The one exception is the report header's ``computed (UTC)`` line of the
Markdown and HTML reports: it states the time of each run, which may differ by a
second; every other line is compared. The numbers are checked against independent
references: PROJ (pyproj) for the Helmert transform, the known parameters and the
known drift the inputs were made with. For slam and detect the result objects are
checked against the files they wrote, read back here.
"""

from __future__ import annotations

import csv
import json
import math
import re

import laspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pyproj import CRS, Transformer
from scipy.spatial.transform import Rotation

from raytrace.fileio import json_text
from sensors import Trajectory
from survey.adjust.controlpoints import ControlPoints, read_control_points
from survey.adjust.helmert import from_parameters
from survey.analysis.trajectory import trajectory_errors
from survey.cli.main import main
from survey.errors import DriftError, HelmertError, StudyError
from survey.workflows.adjust import adjust_files, correct_file, transform_file
from survey.workflows.detect import detect_study

UTM = np.array([451_000.0, 5_352_000.0, 600.0])
#: The header line stating when a report was computed: the only line allowed to differ.
TIME_LINE = "computed (UTC)"
#: The true Helmert of the control points: translation (m), rotation (arcsec), ppm.
T_TRUE, R_TRUE, S_TRUE = UTM, np.array([10.0, -5.0, 300.0]), 5.0


def _without_time(text: str) -> list[str]:
    lines = text.splitlines()
    assert sum(TIME_LINE in ln for ln in lines) == 1
    return [ln for ln in lines if TIME_LINE not in ln]


def same_files(a, b):
    """Assert folders ``a`` and ``b`` hold the same file names and bytes, the reports'
    ``computed (UTC)`` line excepted (and that line is there in both)."""
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for n in names:
        x, y = (a / n).read_bytes(), (b / n).read_bytes()
        if n.endswith((".md", ".html")):
            assert _without_time(x.decode()) == _without_time(y.decode()), n
        else:
            assert x == y, n
    return names


def _xyz(path):
    las = laspy.read(path)
    return np.stack([las.x, las.y, las.z], 1)


# ------------------------------------------------------------------ adjust, transform
@pytest.fixture(scope="module")
def control(tmp_path_factory):
    """Ten control points (2 mm noise; P3 off by 3 cm, a blunder for the snooping),
    the target stating EPSG:32632, and a LAS cloud with GPS time in the source
    system."""
    d = tmp_path_factory.mktemp("adjwf")
    rng = np.random.default_rng(7)
    src = rng.uniform(-100, 100, (10, 3))
    h = from_parameters(T_TRUE, R_TRUE, S_TRUE)
    dst = h.apply(src) + rng.normal(0, 0.002, src.shape)
    dst[3] += [0.03, -0.01, 0.0]
    ids = [f"P{i}" for i in range(10)]
    ControlPoints(ids, src).write(d / "src.csv")
    p = ControlPoints(ids, dst, np.full((10, 3), 0.002)).write(d / "dst.csv")
    p.write_text("# crs: EPSG:32632\n" + p.read_text())
    cloud = rng.uniform(-90, 90, (3000, 3))
    hdr = laspy.LasHeader(point_format=6, version="1.4")
    hdr.scales = [1e-4] * 3
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = cloud.T
    las.gps_time = np.arange(len(cloud), dtype=float)
    las.write(d / "c.las")
    return d


def test_adjust_cli_and_library_write_the_same_files(control, tmp_path, capsys):
    a, b = tmp_path / "cli", tmp_path / "lib"
    a.mkdir()
    b.mkdir()
    src, dst = str(control / "src.csv"), str(control / "dst.csv")
    assert main(["adjust", src, dst, "--snoop", "--exclude", "P9", "--angles", "gon",
                 "--project", "Lot 3", "--instrument", "TS16", "--json",
                 str(a / "h.json"), "--report", str(a / "h.md")]) == 0
    printed = capsys.readouterr().out
    res = adjust_files(src, dst, snoop=True, exclude=["P9"], angles="gon",
                       project="Lot 3", instrument="TS16", json_path=b / "h.json",
                       report_path=b / "h.md")
    assert same_files(a, b) == ["h.html", "h.json", "h.md"]
    # What the command prints is the result's report.
    assert _without_time(printed) == _without_time(res.report)
    assert res.json_path == b / "h.json" and res.report_path == b / "h.md"
    # The blunder was snooped out, P9 excluded; the fit recovers the true parameters.
    assert "P3" not in res.helmert.ids and "P9" not in res.helmert.ids
    assert len(res.helmert.ids) == 8
    np.testing.assert_allclose(res.helmert.translation_m, T_TRUE, atol=0.01)
    np.testing.assert_allclose(res.helmert.rotation_arcsec, R_TRUE, atol=10.0)
    assert res.source_crs is None and res.target_crs == "EPSG:32632"
    js = json.loads((b / "h.json").read_text())
    np.testing.assert_allclose(js["translation_m"], res.helmert.translation_m, rtol=0,
                               atol=1e-9)
    assert js["project"] == "Lot 3" and js["unmatched_ids"] is None
    # Options change the result: without snooping the blunder stays in.
    plain = adjust_files(src, dst)
    assert "P3" in plain.helmert.ids and plain.json_path is None
    assert plain.report != res.report


def test_transform_cli_and_library_write_the_same_cloud(control, tmp_path, capsys):
    h = tmp_path / "h.json"
    adjust_files(control / "src.csv", control / "dst.csv", snoop=True, json_path=h)
    cli, lib = tmp_path / "cli.laz", tmp_path / "lib.laz"
    assert main(["transform", str(control / "c.las"), "--helmert", str(h), "-o",
                 str(cli)]) == 0
    printed = capsys.readouterr().out
    res = transform_file(control / "c.las", h, lib)
    assert cli.read_bytes() == lib.read_bytes()
    n = len(laspy.read(lib).x)
    assert res.points == n == 3000 and res.output == lib and not res.inverse
    # The output states the target CRS the JSON records (as WKT2).
    assert CRS.from_user_input(res.crs).equals(CRS.from_epsg(32632))
    assert res.crs_label == "EPSG:32632 (WGS 84 / UTM zone 32N)"
    assert printed == f"transformed {n:,} points -> {cli} ({res.crs_label})\n"
    # Independent reference: PROJ applies the pipeline the JSON records.
    js = json.loads(h.read_text())
    src = _xyz(control / "c.las")
    want = np.array(Transformer.from_pipeline(js["proj"]).transform(*src.T)).T
    np.testing.assert_allclose(_xyz(lib), want, rtol=0, atol=1.5e-4)
    # inverse=True changes the output, and undoes the transform to the LAS grid; the
    # source states no CRS, so the output states none (with a warning).
    back = tmp_path / "back.laz"
    with pytest.warns(UserWarning, match="states no CRS"):
        inv = transform_file(lib, h, back, inverse=True)
    assert inv.inverse and inv.crs is None and inv.crs_label is None
    np.testing.assert_allclose(_xyz(back), src, rtol=0, atol=2.5e-4)


def test_transform_refuses_a_missing_or_bad_helmert(control, tmp_path):
    with pytest.raises(HelmertError, match="Helmert JSON .* does not exist"):
        transform_file(control / "c.las", tmp_path / "none.json", tmp_path / "x.laz")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(HelmertError, match="Expected JSON in"):
        transform_file(control / "c.las", tmp_path / "bad.json", tmp_path / "x.laz")
    assert not (tmp_path / "x.laz").exists()


@settings(max_examples=20, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(t=st.tuples(*[st.floats(-1e5, 1e5)] * 3), r=st.tuples(*[st.floats(-3e4, 3e4)] * 3),
       s=st.floats(-500.0, 500.0))
def test_transform_then_inverse_is_the_identity(t, r, s, control, tmp_path_factory):
    """Property: for any similarity, the inverse transform of the transformed cloud
    gives the input back within the LAS grids of the two files (0.1 mm each)."""
    d = tmp_path_factory.mktemp("rt")
    h = from_parameters(t, r, s)
    (d / "h.json").write_text(json.dumps(h.to_dict()))
    transform_file(control / "c.las", d / "h.json", d / "a.las")
    transform_file(d / "a.las", d / "h.json", d / "b.las", inverse=True)
    np.testing.assert_allclose(_xyz(d / "b.las"), _xyz(control / "c.las"), rtol=0,
                               atol=3e-4)


# ------------------------------------------------------------------ correct
@pytest.fixture(scope="module")
def drifted(tmp_path_factory):
    """A straight 100 s run with a known linear drift (20 cm lateral, 5 cm vertical at
    100 s): trajectory, LAZ with GPS time, control points in both frames."""
    d = tmp_path_factory.mktemp("corwf")
    t = np.linspace(0, 100, 201)
    true_pos = np.stack([t, 0 * t, 0 * t + 1.0], 1) + UTM
    drift = np.stack([0 * t, 0.002 * t, 0.0005 * t], 1)
    Trajectory(t, true_pos + drift, Rotation.identity(len(t))).write(d / "slam.txt")
    ids, g, m, tau = [], [], [], []
    for k, c in enumerate(np.arange(5.0, 100.0, 10.0)):
        for j, (dy, dz) in enumerate(((1.4, 1.0), (-1.4, 1.0), (0.0, 2.8))):
            ids.append(f"S{k}_{j}")
            p = UTM + [c, dy, dz]
            g.append(p)
            m.append(p + drift[int(c * 2)])
            tau.append(c)
    ControlPoints(ids, np.array(g), np.full((len(g), 3), 0.0015)).write(d / "cp.csv")
    ControlPoints(ids, np.array(m), time=np.array(tau)).write(d / "cp_mls.csv")
    rng = np.random.default_rng(1)
    tt = rng.uniform(5, 95, 2000)
    truth = np.stack([UTM[0] + tt, UTM[1] + rng.uniform(-1.4, 1.4, 2000),
                      UTM[2] + rng.uniform(0, 2.8, 2000)], 1)
    hdr = laspy.LasHeader(point_format=6, version="1.4")
    hdr.scales = [1e-4] * 3
    hdr.offsets = UTM
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = (truth + np.stack([0 * tt, 0.002 * tt, 0.0005 * tt], 1)).T
    las.gps_time = tt
    las.write(d / "mls.laz")
    np.save(d / "truth.npy", truth)
    return d


def test_correct_cli_and_library_write_the_same_files(drifted, tmp_path, capsys):
    d = drifted
    a, b = tmp_path / "cli", tmp_path / "lib"
    a.mkdir()
    b.mkdir()
    ins = [str(d / "slam.txt"), str(d / "mls.laz"), str(d / "cp.csv"), str(d / "cp_mls.csv")]
    assert main(["correct", "--trajectory", ins[0], "--cloud", ins[1], "--control", ins[2],
                 "--observed", ins[3], "-o", str(a / "fixed.laz"), "--json",
                 str(a / "fixed.json"), "--project", "Lot 3"]) == 0
    printed = capsys.readouterr().out
    res = correct_file(*ins, b / "fixed.laz", json_path=b / "fixed.json", project="Lot 3")
    assert same_files(a, b) == ["fixed.json", "fixed.laz", "fixed_correction.png",
                                "fixed_report.html", "fixed_report.md",
                                "fixed_trajectory.txt"]
    assert printed == (f"corrected {res.points:,} points with {res.control_points} "
                       f"control points (piecewise); check-point RMS "
                       f"{res.check_rms_m * 1000:.1f} mm -> {a / 'fixed.laz'}, "
                       "fixed_trajectory.txt, fixed_report.md\n")
    # The result's numbers are the files' and the inputs' truth.
    js = json.loads((b / "fixed.json").read_text())
    assert js == {"model": "piecewise", "control_points": 30, "points": 2000,
                  "check_rms_m": res.check_rms_m, "check_max_m": res.check_max_m,
                  "correction_max_m": res.correction_max_m}
    assert res.points == len(laspy.read(b / "fixed.laz").x)
    assert res.check_residuals_m.shape == (30, 3)
    # The drift at the trajectory's ends is |(0, 0.2, 0.05)| m at 100 s.
    assert res.correction_max_m == pytest.approx(math.hypot(0.2, 0.05), abs=0.01)
    assert np.abs(_xyz(b / "fixed.laz") - np.load(d / "truth.npy")).max() < 0.004
    # model="global" is another correction (one similarity): another cloud.
    glob = correct_file(*ins, tmp_path / "g.laz", model="global")
    assert glob.model == "global"
    assert (tmp_path / "g.laz").read_bytes() != (b / "fixed.laz").read_bytes()


def test_correct_refuses_control_points_outside_the_run(drifted, tmp_path):
    d = drifted
    cp = read_control_points(d / "cp_mls.csv")
    ControlPoints(cp.ids, cp.xyz, time=cp.time + 500.0).write(tmp_path / "late.csv")
    with pytest.raises(DriftError, match=r"within the trajectory's \[0, 100\] s"):
        correct_file(d / "slam.txt", d / "mls.laz", d / "cp.csv", tmp_path / "late.csv",
                     tmp_path / "x.laz")
    assert not (tmp_path / "x.laz").exists()


# ------------------------------------------------------------------ slam
@pytest.fixture(scope="module")
def slam_run(tmp_path_factory):
    """A 2 s Airy drive (full fields) past the prisms at 12.5 m, and ``slam_file`` on
    it with the truth, the re-placed cloud and the control points."""
    pytest.importorskip("kiss_icp")
    from survey.workflows.slam import slam_file

    d = tmp_path_factory.mktemp("slamwf")
    assert main(["tunnel", "--preset", "bfo", "--edge-length", "0.25", "--roughness-mm",
                 "100", "-o", str(d / "t.ply"), "--quiet"]) == 0
    assert main(["drive", "--mesh", str(d / "t.ply"), "--along", "centreline", "--speed",
                 "1", "--chainage", "11.5,13.5", "--fields", "full", "--quiet", "-o",
                 str(d / "airy.laz")]) == 0
    seen = []
    res = slam_file(d / "airy.laz", d / "est.txt", truth=d / "airy_true_trajectory.txt",
                    cloud=d / "mls.laz", control=d / "t.json", seed=3,
                    on_start=seen.append)
    return d, res, seen


def test_slam_result_is_what_its_files_say(slam_run):
    d, res, seen = slam_run
    # on_start got the drive before the odometry ran: its points are the file's.
    assert len(seen) == 1 and seen[0].n_points == len(laspy.read(d / "airy.laz").x)
    assert [p.name for p in res.written] == [
        "est.txt", "est_report.md", "est.json", "est.png", "mls.laz",
        "mls_cp_observed.csv", "mls_cp_world.csv"]
    assert all(p.is_file() for p in res.written) and (d / "est_report.html").is_file()
    est = Trajectory.read(d / "est.txt")
    np.testing.assert_allclose(est.times, res.trajectory.times, rtol=0, atol=1e-9)
    np.testing.assert_allclose(est.positions, res.trajectory.positions, rtol=0, atol=1e-8)
    # The evaluation, redone here from the files alone, is the result's and the JSON's.
    err = trajectory_errors(est, Trajectory.read(d / "airy_true_trajectory.txt")).to_dict()
    js = json.loads((d / "est.json").read_text())
    for key in ("ate_rms_m", "final_error_m", "final_error_pct", "path_length_m"):
        assert getattr(res, key) == pytest.approx(err[key], rel=1e-6, abs=1e-9), key
        assert js[key] == getattr(res, key), key
    for key in ("odometry", "frames", "skipped_frames", "points", "voxel_size_m"):
        assert js[key] == res.summary[key], key
    assert js["frames"] == len(res.odometry.times) >= 10
    assert res.path_length_m == pytest.approx(2.0, abs=0.05)
    # The re-placed cloud holds every point of the drive; the control points observed
    # in it are the prisms at 12.5 m, in both files.
    assert res.cloud_points == len(laspy.read(d / "mls.laz").x) == seen[0].n_points
    observed = read_control_points(res.observed_path)
    world = read_control_points(res.world_path)
    assert len(observed.ids) == 3 and set(observed.ids) <= set(world.ids)
    assert np.all((observed.time > est.start_s) & (observed.time < est.end_s))
    assert f"{js['ate_rms_m']:.3f}" in (d / "est_report.md").read_text()


def _close(x, y, where="json"):
    """``x`` equals ``y`` (nested dicts and lists), floats to 1e-9 relative."""
    if isinstance(y, dict):
        assert isinstance(x, dict) and x.keys() == y.keys(), where
        for k in y:
            _close(x[k], y[k], f"{where}.{k}")
    elif isinstance(y, list):
        assert isinstance(x, list) and len(x) == len(y), where
        for i, (a, b) in enumerate(zip(x, y)):
            _close(a, b, f"{where}[{i}]")
    elif isinstance(y, float):
        assert x == pytest.approx(y, rel=1e-9, abs=1e-12), where
    else:
        assert x == y, where


def test_slam_cli_writes_what_the_library_writes(slam_run, tmp_path, capsys):
    """The command on the same drive writes the same files, but for the JSON's
    ``odometry_seconds`` (the wall time of each run), the reports' time line, and the
    JSON's figures in their last digits: KISS-ICP's poses differ between runs in the
    last bits (its parallel reductions; measured 1e-14 relative), below the 1 ns /
    1 nm digits of the trajectory file and the LAS grid, which are identical."""
    d, res, seen = slam_run
    c = tmp_path
    assert main(["slam", str(d / "airy.laz"), "-o", str(c / "est.txt"), "--truth",
                 str(d / "airy_true_trajectory.txt"), "--cloud", str(c / "mls.laz"),
                 "--control", str(d / "t.json"), "--seed", "3"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == (f"kiss-icp on {seen[0].n_points:,} points of robosense_airy "
                      f"({seen[0].time_span_s[1] - seen[0].time_span_s[0]:.1f} s)...")
    assert out[1].endswith(" -> " + ", ".join(p.name for p in res.written))
    assert f"ATE RMS {100 * res.ate_rms_m:.1f} cm" in out[1]
    for p in res.written:
        x, y = (c / p.name).read_bytes(), p.read_bytes()
        if p.suffix == ".json":
            jx, jy = json.loads(x), json.loads(y)
            assert jx.pop("odometry_seconds") > 0 and jy.pop("odometry_seconds") > 0
            _close(jx, jy)
        elif p.suffix == ".md":
            assert _without_time(x.decode()) == _without_time(y.decode())
        else:
            assert x == y, p.name


def test_slam_checks_its_options_before_it_runs(slam_run, tmp_path):
    from survey.errors import OdometryError
    from survey.workflows.slam import slam_file

    d, _, _ = slam_run
    called = []
    for kw, match in (({"output": tmp_path / "e.las"}, "trajectory file"),
                      ({"cloud": tmp_path / "c.ply"}, "--cloud as .las/.laz"),
                      ({"place": d / "airy.laz"}, "--cloud OUT.laz with --place"),
                      ({"control": d / "t.json"}, "--truth and --cloud")):
        kw = {"output": tmp_path / "e.txt", **kw}
        with pytest.raises(OdometryError, match=re.escape(match)):
            slam_file(d / "airy.laz", on_start=called.append, **kw)
    assert not called and not list(tmp_path.iterdir())


# ------------------------------------------------------------------ detect
#: A small study: one TLS, one noise factor, two magnitudes on a coarse tube.
SMALL = {"quick": True, "edge_length_m": 0.3, "noises": [1.0],
         "magnitudes_m": [0.005, 0.01], "core_spacing_m": 0.2}


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    d = tmp_path_factory.mktemp("detwf")
    ticks = []
    res = detect_study(d / "lib", project="Lot 3", progress=lambda i, n: ticks.append((i, n)),
                       **SMALL)
    return d, res, ticks


def test_detect_result_is_what_its_files_say(study):
    d, res, ticks = study
    assert sorted(p.name for p in res.folder.iterdir()) == [
        "detect.csv", "detect.html", "detect.json", "detect.md", "detect.png",
        "targets.csv"]
    assert ticks == [(1, 1)] and len(res.rows) == 1
    js = json.loads(res.json_path.read_text())
    assert js["quick"] is True and js["resolution"] == "preview"
    # The rows as the file holds them (strict JSON: NaN is null).
    assert js["rows"] == json.loads(json_text([r.to_dict() for r in res.rows]))
    with open(res.csv_path, newline="") as fh:
        lines = list(csv.DictReader(fh))
    row = res.rows[0]
    assert {ln["sensor"] for ln in lines} == {row.sensor}
    for ln in lines:
        want, got = row.detectable_m[ln["kind"]], float(ln["detectable_m"])   # 6 digits
        assert (math.isnan(got) and math.isnan(want)) or got == pytest.approx(want,
                                                                              rel=1e-5), ln
        assert float(ln["false_alarm_rate"]) == pytest.approx(row.false_alarm_rate,
                                                              rel=1e-5, abs=1e-12)
    # The report is the result's Markdown with the header the user asked for below
    # its title.
    md = res.report_path.read_text().splitlines()
    assert "| project | Lot 3 |" in md and "| tunnel | preset tbm |" in md
    body = res.markdown.rstrip("\n").splitlines()
    assert md[0] == body[0] == "# Detectability study"
    assert md[-(len(body) - 1):] == body[1:] and len(md) > len(body) + 5


def test_detect_cli_writes_what_the_library_writes(study, capsys):
    d, res, _ = study
    assert main(["detect", "--quick", "--edge-length", "0.3", "--noise", "1",
                 "--magnitudes", "5,10", "--core-spacing", "0.2", "--project", "Lot 3",
                 "-o", str(d / "cli")]) == 0
    printed = capsys.readouterr().out
    same_files(d / "cli", res.folder)
    assert printed == res.markdown.rstrip() + (
        f"\n-> {d / 'cli'}/ (detect.json, detect.csv, targets.csv, detect.md, "
        "detect.png)\n")


def test_detect_refuses_an_edge_length_with_a_mesh_and_a_full_folder(study, tmp_path):
    d, res, _ = study
    with pytest.raises(StudyError, match="only without mesh"):
        detect_study(tmp_path / "x", mesh=d / "t.ply", edge_length_m=0.2)
    with pytest.raises(StudyError, match="holds files; pass --force"):
        detect_study(res.folder, **SMALL)
