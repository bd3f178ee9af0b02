"""Issue 32: ``tunnelsim compare`` as a library call (``survey.workflows.compare``).

Notebook-style: the command (``survey.cli.main.main`` in-process) and
``compare_files`` run on the same small inputs into two folders and must write the same
files, byte for byte. The one exception is the report header's ``computed (UTC)`` line
of stats.md and stats.html: it states the time of each run, which may differ by a
second; every other line is compared. The result object's numbers are checked against
the stats.csv the run wrote and against brute-force nearest neighbours and point-to-
triangle distances computed here in NumPy.
"""

from __future__ import annotations

import contextlib
import csv

import laspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sensors.io.cloudmap import write_points_las
from survey.analysis.compare import STAT_FIELDS
from survey.cli.main import main
from survey.errors import CompareError
from survey.world.mesh import write_ply
from survey.workflows.compare import CompareResult, compare_files, output_folder

UTM = np.array([500_000.0, 5_400_000.0, 300.0])
#: The header line stating when a report was computed: the only line allowed to differ.
TIME_LINE = "computed (UTC)"


def same_files(a, b):
    """Assert folders ``a`` and ``b`` hold the same file names and bytes, the reports'
    ``computed (UTC)`` line excepted (and that line is there in both)."""
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for n in names:
        x, y = (a / n).read_bytes(), (b / n).read_bytes()
        if n.endswith((".md", ".html")):
            lx, ly = x.decode().splitlines(), y.decode().splitlines()
            assert sum(TIME_LINE in ln for ln in lx) == 1, n
            x = "\n".join(ln for ln in lx if TIME_LINE not in ln).encode()
            y = "\n".join(ln for ln in ly if TIME_LINE not in ln).encode()
        assert x == y, n
    return names


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    """A rough floor (reference), a scan of it lifted 2 cm and a second scan as XYZ."""
    d = tmp_path_factory.mktemp("cmpwf")
    rng = np.random.default_rng(11)
    ref = np.c_[rng.uniform(0, 6, (1500, 2)), rng.normal(0, 0.003, 1500)] + UTM
    a = np.c_[rng.uniform(0.5, 5.5, (600, 2)), 0.02 + rng.normal(0, 0.003, 600)] + UTM
    b = np.c_[rng.uniform(0.5, 5.5, (400, 2)), -0.01 + rng.normal(0, 0.003, 400)] + UTM
    write_points_las(d / "ref.laz", ref)
    write_points_las(d / "a.laz", a)
    np.savetxt(d / "b.xyz", b - [0, 0, 0], fmt="%.4f")
    # A plate of two triangles under the floor as a mesh reference.
    v = np.array([[-1, -1, 0], [7, -1, 0], [7, 7, 0], [-1, 7, 0]], float) + UTM
    write_ply(d / "plate.ply", v, np.array([[0, 1, 2], [0, 2, 3]]))
    return d


def _read_stats_csv(path):
    with open(path, newline="") as fh:
        return {row["scan"]: row for row in csv.DictReader(fh)}


def _brute_c2c(q, ref):
    """Nearest reference point distance of every query point, all pairs in float64."""
    d2 = ((q[:, None, :] - ref[None, :, :]) ** 2).sum(-1)
    return np.sqrt(d2.min(1))


def _xyz(path):
    las = laspy.read(path)
    return np.stack([las.x, las.y, las.z], 1), np.asarray(las["distance"], np.float64)


# ---------------------------------------------------------------------- CLI == library
@pytest.mark.parametrize("ref,extra,kw", [
    ("ref.laz", [], {}),
    ("ref.laz", ["--max-dist", "0.015", "--split"],
     dict(max_distance_m=0.015, split=True)),
    ("plate.ply", [], {}),
    ("ref.laz", ["--tile-m", "2", "--max-dist", "0.5"],
     dict(tile_m=2.0, max_distance_m=0.5)),
    ("plate.ply", ["--tile-m", "2.5"], dict(tile_m=2.5)),
])
def test_the_command_and_the_library_write_the_same_files(clouds, tmp_path, ref, extra,
                                                          kw):
    inputs = [str(clouds / "a.laz"), str(clouds / "b.xyz"), str(clouds / ref)]
    cli, lib = tmp_path / "cli", tmp_path / "lib"
    assert main(["compare", *inputs, "-o", str(cli), "--quiet", "--project", "P 1",
                 *extra]) == 0
    r = compare_files(inputs[:2], inputs[2], lib, project="P 1", **kw)
    names = same_files(cli, lib)
    assert names == sorted(["a_distance.laz", "b_distance.laz", "histogram.png",
                            "stats.csv", "stats.html", "stats.md"])
    assert sorted(p.name for p in r.files) == names
    assert r.kind == ("mesh" if ref.endswith(".ply") else "cloud")
    assert (r.tiles is None) == ("tile_m" not in kw) and (r.tiles is None or r.tiles > 0)
    assert "| project | P 1 |" in (lib / "stats.md").read_text()


def test_the_command_prints_the_results_table(clouds, tmp_path, capsys):
    inputs = [str(clouds / "a.laz"), str(clouds / "ref.laz")]
    assert main(["compare", *inputs, "-o", str(tmp_path / "c")]) == 0
    printed = capsys.readouterr().out
    r = compare_files(inputs[:1], inputs[1], tmp_path / "l")
    assert printed.startswith(r.table.rstrip() + f"\n-> {tmp_path / 'c'}/ (stats.csv")
    assert f"| a | 600 | {1000 * r.stats['a']['mean']:.2f} |" in printed


# ---------------------------------------------------------------------- the numbers
def test_result_numbers_are_the_stats_csv_and_brute_force(clouds, tmp_path):
    r = compare_files([clouds / "a.laz", clouds / "b.xyz"], clouds / "ref.laz",
                      tmp_path / "o")
    assert isinstance(r, CompareResult) and r.title == "C2C"
    rows = _read_stats_csv(tmp_path / "o" / "stats.csv")
    assert sorted(rows) == sorted(r.stats) == ["a", "b"]
    for name, row in rows.items():
        assert int(row["n"]) == r.stats[name]["n"]
        for f in STAT_FIELDS[1:]:
            assert float(row[f + "_m"]) == pytest.approx(r.stats[name][f], abs=5e-7)
    ref = laspy.read(clouds / "ref.laz")
    ref = np.stack([ref.x, ref.y, ref.z], 1)
    for name, path in (("a", r.distance_files[0]), ("b", r.distance_files[1])):
        q, stored = _xyz(path)
        want = _brute_c2c(q, ref)
        np.testing.assert_allclose(stored, want, atol=1e-6)     # float32 field
        s = r.stats[name]
        assert s["n"] == len(q)
        assert s["rms"] == pytest.approx(np.sqrt(np.mean(want ** 2)), abs=1e-9)
        assert s["median"] == pytest.approx(np.median(want), abs=1e-9)
        assert s["max_abs"] == pytest.approx(want.max(), abs=1e-9)


def test_mesh_distances_are_signed_heights_above_the_plate(clouds, tmp_path):
    """C2M to a horizontal plate whose normal is +z: the distance is z - plate's z."""
    r = compare_files([clouds / "a.laz"], clouds / "plate.ply", tmp_path / "m")
    q, stored = _xyz(r.distance_files[0])
    np.testing.assert_allclose(stored, q[:, 2] - UTM[2], atol=1e-5)
    assert r.title == "C2M (signed)"
    assert r.stats["a"]["mean"] == pytest.approx(np.mean(q[:, 2] - UTM[2]), abs=1e-6)


def test_options_change_the_output(clouds, tmp_path):
    """--max-dist clamps, --split adds the components compared - nearest."""
    plain = compare_files([clouds / "a.laz"], clouds / "ref.laz", tmp_path / "p")
    clamp = compare_files([clouds / "a.laz"], clouds / "ref.laz", tmp_path / "c",
                          max_distance_m=0.015, split=True)
    assert clamp.stats["a"]["max_abs"] <= 0.015 < plain.stats["a"]["max_abs"]
    las = laspy.read(clamp.distance_files[0])
    assert {"dx", "dy", "dz"} <= set(las.point_format.extra_dimension_names)
    assert "dx" not in set(laspy.read(plain.distance_files[0]).point_format
                           .extra_dimension_names)
    ok = np.asarray(las["distance"]) < 0.0149
    comp = np.stack([las["dx"], las["dy"], las["dz"]], 1).astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(comp[ok], axis=1),
                               np.asarray(las["distance"])[ok], atol=1e-5)
    assert "clamped" in (tmp_path / "c" / "stats.md").read_text()
    assert "clamped" not in (tmp_path / "p" / "stats.md").read_text()


@settings(max_examples=8, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 60), m=st.integers(1, 80),
       tile=st.sampled_from([None, 0.7, 3.0]))
def test_any_clouds_give_brute_force_distances_whole_or_tiled(tmp_path_factory, seed, n,
                                                             m, tile):
    rng = np.random.default_rng(seed)
    d = tmp_path_factory.mktemp("prop")
    ref = rng.uniform(0, 3, (m, 3)) + UTM
    q = rng.uniform(0, 3, (n, 3)) + UTM
    write_points_las(d / "r.laz", ref)
    write_points_las(d / "q.laz", q)
    # The halo (5.5 m) covers the 3 m cube's diagonal: the tiles miss no neighbour,
    # and it is larger than the tiles, which the library warns about.
    with pytest.warns(UserWarning, match="larger than --tile-m") if tile else \
            contextlib.nullcontext():
        r = compare_files([d / "q.laz"], d / "r.laz", d / "o", tile_m=tile,
                          max_distance_m=None if tile is None else 5.5,
                          allow_disjoint=True)
    qq, stored = _xyz(r.distance_files[0])
    want = _brute_c2c(qq, np.stack([laspy.read(d / "r.laz").x, laspy.read(d / "r.laz").y,
                                    laspy.read(d / "r.laz").z], 1))
    np.testing.assert_allclose(stored, want, atol=1e-6)
    assert r.stats["q"]["n"] == n
    assert r.stats["q"]["rms"] == pytest.approx(np.sqrt(np.mean(want ** 2)), abs=1e-9)


# ---------------------------------------------------------------------- errors
def test_library_errors_name_what_to_do(clouds, tmp_path):
    with pytest.raises(CompareError, match="Expected a compared cloud, got '.*nope.laz'"):
        compare_files([clouds / "nope.laz"], clouds / "ref.laz", tmp_path / "x")
    with pytest.raises(CompareError, match="positive number of metres, got -1"):
        compare_files([clouds / "a.laz"], clouds / "ref.laz", tmp_path / "x", tile_m=-1)
    with pytest.raises(CompareError, match="only with a reference cloud, got a mesh"):
        compare_files([clouds / "a.laz"], clouds / "plate.ply", tmp_path / "x",
                      split=True)
    with pytest.raises(CompareError, match="Expected --max-dist with --tile-m"):
        compare_files([clouds / "a.laz"], clouds / "ref.laz", tmp_path / "x", tile_m=2)
    with pytest.raises(CompareError, match="at least one compared cloud"):
        compare_files([], clouds / "ref.laz", tmp_path / "x")
    assert not (tmp_path / "x").exists()
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "mine.txt").write_text("keep")
    with pytest.raises(CompareError, match="holds files; pass --force"):
        compare_files([clouds / "a.laz"], clouds / "ref.laz", tmp_path / "full")
    r = compare_files([clouds / "a.laz"], clouds / "ref.laz", tmp_path / "full",
                      force=True)
    assert (tmp_path / "full" / "mine.txt").read_text() == "keep"
    assert r.distance_files[0].is_file()


def test_output_folder_refuses_a_file_and_a_missing_parent(tmp_path):
    (tmp_path / "f").write_text("")
    with pytest.raises(CompareError, match="which is a file"):
        output_folder(tmp_path / "f")
    with pytest.raises(CompareError, match="existing parent folder"):
        output_folder(tmp_path / "no" / "o")
    assert output_folder(tmp_path / "new").is_dir()


def test_progress_counts_every_point(clouds, tmp_path):
    calls = []
    compare_files([clouds / "a.laz", clouds / "b.xyz"], clouds / "ref.laz", tmp_path / "o",
                  progress=lambda done, total: calls.append((done, total)))
    assert calls and calls[-1] == (1000, 1000)
    assert all(t == 1000 for _, t in calls) and [c for c, _ in calls] == sorted(
        c for c, _ in calls)
    tiles = {}
    compare_files([clouds / "a.laz"], clouds / "ref.laz", tmp_path / "t", tile_m=2.0,
                  max_distance_m=0.5,
                  tile_progress=lambda c: lambda d, t: tiles.setdefault(c, []).append(
                      (d, t)))
    (cloud, got), = tiles.items()
    assert cloud.endswith("a.laz") and got[-1][0] == got[-1][1] > 1
