"""C2C and C2M distances against brute force and a hand-built case; statistics, outputs
and the ``compare`` command."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from survey.cli.main import main
from survey.errors import CompareError
from survey.analysis.compare import (ReferenceCloud, cloud_to_cloud, cloud_to_mesh, distance_stats)
from survey.report.compare import plot_histogram, stats_csv, stats_markdown
from tests.naive import naive_nearest, naive_point_mesh

UTM = np.array([512_345.0, 5_412_345.0, 312.0])


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 400), st.integers(1, 300))
def test_c2c_equals_brute_force(seed, n_ref, n_cmp):
    rng = np.random.default_rng(seed)
    ref = rng.normal(size=(n_ref, 3)) * 2 + UTM
    cmp_ = rng.normal(size=(n_cmp, 3)) * 2.5 + UTM
    d_naive, i_naive = naive_nearest(cmp_, ref)
    r = cloud_to_cloud(cmp_, ref, split=True)
    np.testing.assert_allclose(r.distance, d_naive, rtol=0, atol=1e-9)
    # Split components are compared - nearest reference.
    np.testing.assert_allclose(np.stack([r.dx, r.dy, r.dz], 1), cmp_ - ref[r.nearest],
                               atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(cmp_ - ref[r.nearest], axis=1), d_naive,
                               atol=1e-9)


def test_c2c_max_dist_clamps():
    rng = np.random.default_rng(3)
    ref = rng.uniform(0, 10, size=(500, 3))
    cmp_ = rng.uniform(-5, 15, size=(800, 3))
    full, _ = naive_nearest(cmp_, ref)
    r = cloud_to_cloud(cmp_, ref, max_distance_m=0.6, split=True)
    far = full > 0.6
    assert far.any() and (~far).any()
    np.testing.assert_allclose(r.distance[~far], full[~far], atol=1e-12)
    assert (r.distance[far] == 0.6).all()
    assert np.isnan(r.dx[far]).all() and (r.nearest[far] == -1).all()
    assert np.isfinite(r.dx[~far]).all()


def test_c2c_plane_model_removes_the_sampling():
    # Reference: a 2 cm grid on z = 0; compared points 5 mm above, off the grid nodes.
    g = np.arange(0, 2.0001, 0.02)
    X, Y = np.meshgrid(g, g)
    ref = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1) + UTM
    rng = np.random.default_rng(0)
    cmp_ = np.stack([rng.uniform(0.5, 1.5, 300), rng.uniform(0.5, 1.5, 300),
                     np.full(300, 0.005)], 1) + UTM
    plain = cloud_to_cloud(cmp_, ref).distance
    plane = cloud_to_cloud(cmp_, ref, model="plane", k=6).distance
    np.testing.assert_allclose(plane, 0.005, atol=1e-7)
    assert plain.mean() > 0.008          # nearest node is ~cell/2 away sideways


def _sphere_and_plate():
    import trimesh

    m = trimesh.creation.icosphere(2)
    v = np.vstack([m.vertices * 2.0, [[-6, -6, -3], [6, -6, -3], [0, 6, -3]]]) + UTM
    f = np.vstack([m.faces, [[len(v) - 3, len(v) - 2, len(v) - 1]]])
    return v, f


def test_c2m_equals_brute_force():
    v, f = _sphere_and_plate()
    rng = np.random.default_rng(7)
    p = rng.normal(size=(400, 3)) * 3 + UTM
    r = cloud_to_mesh(p, v, f)
    d, _ = naive_point_mesh(p, v, f)
    np.testing.assert_allclose(np.abs(r.distance), d, atol=1e-9)


def test_c2m_sign_hand_built():
    # One triangle in z = 0, counter-clockwise seen from +z: normal +z.
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.array([[0, 1, 2]])
    p = np.array([[0.2, 0.2, 0.5], [0.2, 0.2, -0.3], [2.0, 0.0, 1.0], [0.5, 0.5, 0.0],
                  [-1.0, -1.0, -1.0]])
    d = cloud_to_mesh(p, v, f).distance
    np.testing.assert_allclose(d, [0.5, -0.3, np.hypot(1.0, 1.0), 0.0, -np.sqrt(3.0)],
                               atol=1e-12)
    # Flipping the winding flips the sign.
    d2 = cloud_to_mesh(p, v, f[:, ::-1]).distance
    np.testing.assert_allclose(d2, -d, atol=1e-12)
    # max_distance_m clamps |d| and keeps the sign.
    d3 = cloud_to_mesh(p, v, f, max_distance_m=0.4).distance
    np.testing.assert_allclose(d3, [0.4, -0.3, 0.4, 0.0, -0.4], atol=1e-12)


def test_stats_and_tables():
    rng = np.random.default_rng(1)
    d = rng.normal(0.002, 0.003, 10_000)
    s = distance_stats(d)
    assert s["n"] == 10_000
    assert s["mean"] == pytest.approx(d.mean()) and s["median"] == pytest.approx(np.median(d))
    assert s["std"] == pytest.approx(d.std()) and s["p95"] == pytest.approx(
        np.percentile(np.abs(d), 95))
    csv = stats_csv({"st1": s}).splitlines()
    assert csv[0].startswith("scan,n,mean_m") and csv[1].startswith("st1,10000,")
    assert float(csv[1].split(",")[2]) == pytest.approx(d.mean(), abs=1e-6)
    md = stats_markdown({"st1": s})
    assert f"{1000 * d.mean():.2f}" in md and "| st1 | 10,000 |" in md


def test_histogram_png(tmp_path):
    rng = np.random.default_rng(2)
    out = plot_histogram({"a": rng.normal(0, 0.01, 5000), "b": rng.normal(0.01, 0.01, 5000)},
                         tmp_path / "h.png")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert (w, h) == (770, 440) and len(data) > 10_000


def test_bad_inputs():
    with pytest.raises(CompareError, match="shape"):
        cloud_to_cloud(np.zeros((3, 2)), np.zeros((3, 3)))
    with pytest.raises(CompareError, match="finite"):
        cloud_to_cloud(np.full((1, 3), np.nan), np.zeros((3, 3)))
    with pytest.raises(CompareError, match="positive max distance"):
        ReferenceCloud(np.zeros((3, 3))).distances(np.zeros((1, 3)), max_distance_m=0)
    with pytest.raises(CompareError, match="faces"):
        cloud_to_mesh(np.zeros((1, 3)), np.zeros((3, 3)), np.array([[0, 1, 5]]))


def test_cli_compare_cloud_to_mesh(tmp_path, capsys):
    import laspy

    from sensors.io.cloudmap import write_points_las
    from survey.world.mesh import write_ply

    v, f = _sphere_and_plate()
    # float64 PLY (trimesh writes float32, which cannot hold UTM-sized coordinates).
    write_ply(tmp_path / "ref.ply", v, f)
    rng = np.random.default_rng(4)
    p = rng.normal(size=(2000, 3)) * 2 + UTM
    write_points_las(tmp_path / "scan1.laz", p)
    out = tmp_path / "cmp"
    assert main(["compare", str(tmp_path / "scan1.laz"), str(tmp_path / "ref.ply"), "-o",
                 str(out), "--quiet"]) == 0
    las = laspy.read(out / "scan1_distance.laz")
    got = np.asarray(las["distance"], dtype=np.float64)
    q = np.stack([las.x, las.y, las.z], 1)
    ref = cloud_to_mesh(q, v, f).distance
    np.testing.assert_allclose(got, ref, atol=1e-6)    # float32 scalar field
    assert (out / "stats.csv").read_text().startswith("scan,n,")
    assert "C2M (signed)" in (out / "stats.md").read_text()
    assert (out / "histogram.png").stat().st_size > 10_000
    # An existing, non-empty output folder is refused; a missing reference too.
    assert main(["compare", str(tmp_path / "scan1.laz"), str(tmp_path / "ref.ply"), "-o",
                 str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    assert main(["compare", str(tmp_path / "scan1.laz"), str(tmp_path / "nope.laz"), "-o",
                 str(tmp_path / "c2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not exist" in err[0]


def test_cli_compare_cloud_to_cloud_split(tmp_path):
    import laspy

    from sensors.io.cloudmap import write_points_las

    rng = np.random.default_rng(5)
    ref = rng.uniform(0, 5, size=(3000, 3)) + UTM
    cmp_ = rng.uniform(0, 5, size=(1000, 3)) + UTM
    write_points_las(tmp_path / "r.laz", ref)
    write_points_las(tmp_path / "c.laz", cmp_)
    assert main(["compare", str(tmp_path / "c.laz"), str(tmp_path / "r.laz"), "-o",
                 str(tmp_path / "o"), "--split", "--max-dist", "0.2", "--quiet"]) == 0
    las = laspy.read(tmp_path / "o" / "c_distance.laz")
    r_las = laspy.read(tmp_path / "r.laz")
    rq = np.stack([r_las.x, r_las.y, r_las.z], 1)
    q = np.stack([las.x, las.y, las.z], 1)
    d, _ = naive_nearest(q, rq)
    np.testing.assert_allclose(las["distance"], np.minimum(d, 0.2), atol=1e-6)
    assert set(["dx", "dy", "dz"]) <= set(las.point_format.extra_dimension_names)


def test_cli_compare_keeps_the_input_fields(tmp_path):
    import laspy

    from sensors.io.cloudmap import write_points_las

    rng = np.random.default_rng(6)
    ref = rng.uniform(0, 5, size=(2000, 3)) + UTM
    cmp_ = rng.uniform(0, 5, size=(700, 3)) + UTM
    write_points_las(tmp_path / "r.laz", ref)
    write_points_las(tmp_path / "c.las", cmp_, extra={"range": rng.uniform(1, 9, 700)},
                     classification=np.full(700, 64, dtype=np.uint8))
    las = laspy.read(tmp_path / "c.las")
    las.intensity = rng.integers(0, 65535, 700).astype(np.uint16)
    las.gps_time = np.arange(700) * 1e-3
    las.write(tmp_path / "c.las")
    assert main(["compare", str(tmp_path / "c.las"), str(tmp_path / "r.laz"), "-o",
                 str(tmp_path / "o"), "--quiet"]) == 0
    a = laspy.read(tmp_path / "c.las")
    b = laspy.read(tmp_path / "o" / "c_distance.laz")
    for f in ("X", "Y", "Z", "intensity", "gps_time", "classification", "range"):
        np.testing.assert_array_equal(np.asarray(a[f]), np.asarray(b[f]), err_msg=f)
    r = laspy.read(tmp_path / "r.laz")
    d, _ = naive_nearest(np.stack([a.x, a.y, a.z], 1), np.stack([r.x, r.y, r.z], 1))
    np.testing.assert_allclose(b["distance"], d, atol=1e-6)


def test_a_cloud_against_its_shifted_copy_gives_a_histogram(tmp_path, capsys):
    """Every distance the same (a copy moved 5 mm along z): the histogram's range has
    to be widened, not refused (it crashed with a NumPy 'too many bins' traceback)."""
    from survey.cli.main import main
    from sensors.io.cloudmap import write_points_las

    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 10, (2000, 2))
    a = np.column_stack([xy, np.zeros(2000)])
    write_points_las(tmp_path / "a.laz", a)
    write_points_las(tmp_path / "b.laz", a + [0.0, 0.0, 0.005])
    rc = main(["compare", str(tmp_path / "b.laz"), str(tmp_path / "a.laz"), "-o",
               str(tmp_path / "out"), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    png = (tmp_path / "out" / "histogram.png").read_bytes()
    assert png[:4] == b"\x89PNG"
    import csv

    row = next(csv.DictReader((tmp_path / "out" / "stats.csv").open()))
    assert float(row["mean_m"]) == pytest.approx(0.005) and float(row["std_m"]) == 0.0
