"""Issue 32: ``tunnelsim m3c2`` and ``tunnelsim convergence`` as library calls
(``survey.workflows.epochs``).

Notebook-style: the command (``survey.cli.main.main`` in-process) and the library
function run on the same small inputs into two folders and must write the same files,
byte for byte; the one exception is the report header's ``computed (UTC)`` line of the
.md/.html reports (the time of each run). The result's numbers are checked against the
JSON the run wrote, against py4dgeo (3DGeo Heidelberg) on the same epochs and
parameters, and against closed forms (chords of a circle, a 5 mm radial convergence).
"""

from __future__ import annotations

import json
import logging

import laspy
import numpy as np
import pytest

from sensors.io.cloudmap import write_points_las
from survey.cli.main import main
from survey.errors import CompareError
from survey.workflows.epochs import (
    ConvergenceResult,
    M3C2FileResult,
    convergence_files,
    m3c2_to_file,
)

from .test_compare_workflow import TIME_LINE, same_files

UTM = np.array([500_000.0, 5_400_000.0, 300.0])
SHIFT_M = 0.005
M3C2_ARGS = ["--cyl-radius", "0.2", "--max-depth", "0.4", "--normal-radii", "0.25,0.4"]
M3C2_KW = dict(cyl_radius_m=0.2, max_depth_m=0.4, normal_radii_m=(0.25, 0.4))


def _surface(rng, n, dz=0.0):
    """A gently waved floor 4 m x 4 m at UTM coordinates, 1 mm noise, raised by dz."""
    xy = rng.uniform(0, 4, (n, 2))
    z = 0.05 * np.sin(xy[:, 0]) + rng.normal(0, 0.001, n) + dz
    return np.c_[xy, z] + UTM


@pytest.fixture(scope="module")
def epochs(tmp_path_factory):
    d = tmp_path_factory.mktemp("m3c2wf")
    rng = np.random.default_rng(7)
    e1, e2 = _surface(rng, 8000), _surface(rng, 8000, SHIFT_M)
    write_points_las(d / "e1.las", e1)
    write_points_las(d / "e2.las", e2)
    write_points_las(d / "core.las", e1[::40])
    return d


def _las(path):
    las = laspy.read(path)
    return las, np.stack([las.x, las.y, las.z], 1)


# ---------------------------------------------------------------------- m3c2
@pytest.mark.parametrize("extra,kw", [
    (["--core-spacing", "0.5"], dict(core_spacing_m=0.5)),
    (["--core", "core.las", "--robust", "--reg-error", "0.001"],
     dict(core="core.las", robust=True, reg_error_m=0.001)),
    (["--core-spacing", "0.5", "--tile-m", "1.5", "--orient", "0,0,-1"],
     dict(core_spacing_m=0.5, tile_m=1.5, orientation="0,0,-1")),
])
def test_m3c2_command_and_library_write_the_same_files(epochs, tmp_path, extra, kw):
    d = epochs
    extra = [str(d / e) if e.endswith(".las") else e for e in extra]
    kw = {k: str(d / v) if isinstance(v, str) and v.endswith(".las") else v
          for k, v in kw.items()}
    (tmp_path / "cli").mkdir()
    (tmp_path / "lib").mkdir()
    e = [str(d / "e1.las"), str(d / "e2.las")]
    assert main(["m3c2", *e, *M3C2_ARGS, *extra, "--quiet", "--instrument", "TS 16",
                 "-o", str(tmp_path / "cli" / "m.las")]) == 0
    r = m3c2_to_file(*e, tmp_path / "lib" / "m.las", instrument="TS 16", **M3C2_KW,
                     **kw)
    names = same_files(tmp_path / "cli", tmp_path / "lib")
    assert names == ["m.json", "m.las", "m.png", "m_report.html", "m_report.md"]
    assert sorted(p.name for p in r.files) == names
    assert "| instrument | TS 16 |" in r.report.read_text()
    assert (r.epoch_points is None) == ("tile_m" in kw)


def test_m3c2_result_is_the_json_the_las_and_py4dgeo(epochs, tmp_path):
    py4dgeo = pytest.importorskip("py4dgeo")
    logging.getLogger("py4dgeo").setLevel(logging.WARNING)
    d = epochs
    seen = []
    # DECISION: depth 0.6 m = 3 slabs of py4dgeo (an odd count): with an even one it
    # counts a core point lying in an epoch on a slab boundary (t = 0) differently
    # (tests/survey/analysis/test_m3c2.py).
    r = m3c2_to_file(d / "e1.las", d / "e2.las", tmp_path / "m.laz", core=d / "core.las",
                     on_read=lambda n1, n2: seen.append((n1, n2)), cyl_radius_m=0.2,
                     max_depth_m=0.6, normal_radii_m=(0.25, 0.4))
    assert isinstance(r, M3C2FileResult) and seen == [(8000, 8000)] == [r.epoch_points]
    assert json.loads(r.json.read_text()) == json.loads(json.dumps(r.summary))
    las, core = _las(r.output)
    dist = np.asarray(las["distance"], np.float64)
    ok = np.isfinite(dist)
    assert r.summary["core_points"] == len(core) == 200
    assert r.summary["with_distance"] == ok.sum() > 190
    assert r.summary["median_m"] == pytest.approx(np.median(dist[ok]), abs=1e-7)
    assert r.summary["significant"] == int(np.asarray(las["significant"]).sum())
    assert r.summary["median_m"] == pytest.approx(SHIFT_M, abs=5e-4)
    # py4dgeo on the same epochs (local coordinates, as its own tests need) with the
    # normals the file states (its own normal estimate differs from ours by ~1e-3 rad).
    e1, e2 = _las(d / "e1.las")[1], _las(d / "e2.las")[1]
    normals = np.stack([las["nx"], las["ny"], las["nz"]], 1).astype(np.float64)
    m = py4dgeo.M3C2(epochs=(py4dgeo.Epoch(e1 - UTM), py4dgeo.Epoch(e2 - UTM)),
                     corepoints=core - UTM, corepoint_normals=normals, cyl_radius=0.2,
                     max_distance=0.6)
    want, unc = m.run()
    np.testing.assert_array_equal(np.isnan(want), ~ok)
    np.testing.assert_array_equal(np.asarray(las["n1"]), unc["num_samples1"])
    np.testing.assert_allclose(dist[ok], want[ok], atol=2e-6)      # float32 field
    np.testing.assert_allclose(np.asarray(las["lod"], np.float64)[ok],
                               unc["lodetection"][ok], atol=2e-6)


def test_m3c2_orientation_changes_the_sign(epochs, tmp_path):
    d = epochs
    up = m3c2_to_file(d / "e1.las", d / "e2.las", tmp_path / "u.las", core_spacing_m=0.5,
                      **M3C2_KW)
    down = m3c2_to_file(d / "e1.las", d / "e2.las", tmp_path / "d.las",
                        core_spacing_m=0.5, orientation=(0, 0, -1), **M3C2_KW)
    assert up.orientation == "z" and down.orientation == "0,0,-1"
    assert down.summary["median_m"] == pytest.approx(-up.summary["median_m"], abs=1e-9)


def test_m3c2_library_errors(epochs, tmp_path):
    d = epochs
    e = (d / "e1.las", d / "e2.las")
    with pytest.raises(CompareError, match=r"Expected -o as .las/.laz, got '.*m.ply'"):
        m3c2_to_file(*e, tmp_path / "m.ply", **M3C2_KW)
    with pytest.raises(CompareError, match="existing folder"):
        m3c2_to_file(*e, tmp_path / "no" / "m.las", **M3C2_KW)
    with pytest.raises(CompareError, match="--tunnel T.json with --orient axis"):
        m3c2_to_file(*e, tmp_path / "m.las", orientation="axis", **M3C2_KW)
    with pytest.raises(CompareError, match="z, axis or X,Y,Z, got '1,2'"):
        m3c2_to_file(*e, tmp_path / "m.las", orientation="1,2", **M3C2_KW)
    with pytest.raises(CompareError, match="positive --tile-m"):
        m3c2_to_file(*e, tmp_path / "m.las", tile_m=0, **M3C2_KW)
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------------- convergence
R_M = 3.0


def _ring(rng, n, r, x0, x1):
    """Points on a cylinder of radius r about the line y = 0, z = 0 (local), x0..x1."""
    a = rng.uniform(0, 2 * np.pi, n)
    x = rng.uniform(x0, x1, n)
    return np.c_[x, r * np.sin(a), r * np.cos(a)] + UTM


@pytest.fixture(scope="module")
def tunnel(tmp_path_factory):
    """A straight alignment (station CSV) along +x, a 3 m tube around it in two epochs
    (the later 5 mm smaller) and four control points per section at 20 and 30 m."""
    d = tmp_path_factory.mktemp("convwf")
    (d / "axis.csv").write_text(f"chainage,E,N,H\n0,{UTM[0]},{UTM[1]},{UTM[2]}\n"
                                f"100,{UTM[0] + 100},{UTM[1]},{UTM[2]}\n")
    rng = np.random.default_rng(5)
    write_points_las(d / "e1.laz", _ring(rng, 40_000, R_M, 10, 40))
    write_points_las(d / "e2.laz", _ring(rng, 40_000, R_M - SHIFT_M, 10, 40))
    ang = np.deg2rad([0, 90, 180, 270])
    for k, r in ((1, R_M), (2, R_M - SHIFT_M)):
        rows = ["id,E,N,H"]
        for s in (20, 30):
            for i, a in enumerate(ang):
                p = UTM + [s, r * np.sin(a), r * np.cos(a)]
                rows.append(f"S{s}P{i},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f}")
        (d / f"cp{k}.csv").write_text("\n".join(rows) + "\n")
    return d


def test_convergence_command_and_library_write_the_same_files(tunnel, tmp_path):
    d = tunnel
    common = ["--tunnel", str(d / "axis.csv"), "--control1", str(d / "cp1.csv"),
              "--control2", str(d / "cp2.csv"), "--sigma-mm", "1", "--band", "0.5"]
    assert main(["convergence", str(d / "e1.laz"), str(d / "e2.laz"), *common, "--at",
                 "20,30", "-o", str(tmp_path / "cli"), "--quiet"]) == 0
    for at, folder in (("20,30", "lib"), ([20.0, 30.0], "lib2")):
        r = convergence_files(tmp_path / folder, d / "axis.csv",
                              epochs=[str(d / "e1.laz"), str(d / "e2.laz")],
                              control1=str(d / "cp1.csv"), control2=str(d / "cp2.csv"),
                              sigma_m=0.001, at_m=at, band_m=0.5)
        names = same_files(tmp_path / "cli", tmp_path / folder)
        assert names == ["chords.csv", "convergence.html", "convergence.json",
                         "convergence.md", "radial.csv", "radial.png"]
        assert sorted(p.name for p in r.files) == names
    assert "| sections | at 20,30 m |" in r.markdown


def test_convergence_numbers_are_the_closed_form(tunnel, tmp_path, capsys):
    d = tunnel
    r = convergence_files(tmp_path / "o", d / "axis.csv", epochs=[d / "e1.laz",
                                                                  d / "e2.laz"],
                          control1=d / "cp1.csv", control2=d / "cp2.csv",
                          sigma_m=0.001, every_m=10.0, band_m=0.5)
    assert isinstance(r, ConvergenceResult)
    assert json.loads((tmp_path / "o" / "convergence.json").read_text()) == \
        json.loads(json.dumps(r.summary))
    # Chords between points 90 and 180 degrees apart on a circle: 2 r sin(dtheta / 2).
    rows = r.summary["chords"]
    assert len(rows) == 12                               # 6 pairs in each of 2 sections
    for c in rows:
        assert c["length1_m"] - c["length2_m"] == pytest.approx(c["convergence_m"],
                                                                abs=1e-12)
        k = c["length1_m"] / R_M                          # 2 sin(dtheta / 2)
        assert c["convergence_m"] == pytest.approx(k * SHIFT_M, abs=1e-6)
        assert c["lod_m"] == pytest.approx(3.92 * 0.001) and c["significant"]
    # Sections every 10 m where both epochs have points (10..40 m less the band).
    got = {round(s["chainage_m"]): s["median_m"] for s in r.summary["sections"]}
    assert sorted(got) == [20, 30]
    for v in got.values():
        assert v == pytest.approx(SHIFT_M, abs=3e-4)
    assert "| sections | every 10 m |" in r.markdown
    # The command prints the report it wrote.
    assert main(["convergence", "--tunnel", str(d / "axis.csv"), "--control1",
                 str(d / "cp1.csv"), "--control2", str(d / "cp2.csv"), "-o",
                 str(tmp_path / "c")]) == 0
    out = capsys.readouterr().out
    assert "-> " + str(tmp_path / "c") + "/ (convergence.md, convergence.html, " \
        "convergence.json, chords.csv)" in out


@pytest.mark.parametrize("kw,match", [
    (dict(epochs=["a"]), "two epochs \\(earlier, later\\) or none, got 1"),
    (dict(control1="cp1.csv"), "--control1 and --control2 together"),
    (dict(), "nothing to compare"),
    (dict(epochs=["e1.laz", "e2.laz"]), "--at S\\[,S...\\] or --every M"),
    (dict(epochs=["e1.laz", "e2.laz"], every_m=100.0), "cover a section every 100 m"),
    (dict(epochs=["e1.laz", "e2.laz"], at_m="20,x"), "--at as comma-separated"),
])
def test_convergence_library_errors(tunnel, tmp_path, kw, match):
    kw = {k: ([str(tunnel / p) for p in v] if isinstance(v, list) else
              str(tunnel / v) if k.startswith("control") else v) for k, v in kw.items()}
    with pytest.raises(CompareError, match=match):
        convergence_files(tmp_path / "o", tunnel / "axis.csv", **kw)
    assert not (tmp_path / "o").exists()


def test_time_line_is_the_only_one_allowed_to_differ():
    """The exception ``same_files`` makes names a line the header writes."""
    from survey.report.header import ReportHeader, header_lines

    assert sum(TIME_LINE in ln for ln in header_lines(ReportHeader())) == 1
