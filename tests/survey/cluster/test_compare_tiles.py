"""compare --tile-m (survey.cluster.compare, issues 19 and 17): distances tile by tile,
with the reference cloud spilled into tiles with a halo of --max-dist, equal bit for bit
to the whole comparison, in this process and on a LocalCluster; bad combinations are
one-line errors.
"""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from survey.analysis.compare import ReferenceCloud, ReferenceMesh
from survey.cli.main import main
from survey.cluster.compare import spill_cloud, tiled_distances
from survey.errors import CompareError

UTM = np.array([512_345.0, 5_403_210.0, 310.0])


def _tube(rng, n, radius, length=40.0, noise=0.003):
    x = rng.uniform(0, length, n)
    a = rng.uniform(0, 2 * np.pi, n)
    p = np.column_stack([x, radius * np.cos(a), radius * np.sin(a)])
    return p + rng.normal(0, noise, (n, 3)) + UTM


def _chunks(p, size):
    return (p[a:a + size] for a in range(0, len(p), size))


def _tiled(compared, reference, tile_m, max_d, split=False, chunk=997):
    with spill_cloud(_chunks(reference, 1500), tile_m, max_d) as ref:
        t = tiled_distances(_chunks(compared, chunk), len(compared), tile_m=tile_m,
                            reference=ref, max_distance_m=max_d, split=split)
    try:
        return np.array(t.distance), None if t.diff is None else np.array(t.diff)
    finally:
        t.close()


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31), st.floats(0.3, 20.0), st.floats(0.05, 1.0))
def test_tiled_c2c_is_the_whole_c2c_bit_for_bit(seed, tile_m, max_d):
    """Any tile size (smaller or larger than the halo), UTM coordinates, some compared
    points beyond --max-dist (clamped), some tiles without reference points."""
    rng = np.random.default_rng(seed)
    ref = _tube(rng, 3000, 3.0, length=20.0)
    cmp_ = np.concatenate([_tube(rng, 2000, 3.02, length=25.0),
                           UTM + rng.uniform(-10, 30, (200, 3))])
    whole = ReferenceCloud(ref).distances(cmp_, max_distance_m=max_d, split=True)
    d, diff = _tiled(cmp_, ref, tile_m, max_d, split=True)
    np.testing.assert_array_equal(d, whole.distance)
    np.testing.assert_array_equal(diff, np.column_stack([whole.dx, whole.dy, whole.dz]))
    assert (d == max_d).any() and (d < max_d).any()


def test_tiled_c2m_is_the_whole_c2m(tmp_path):
    import trimesh

    rng = np.random.default_rng(3)
    m = trimesh.creation.icosphere(subdivisions=3, radius=4.0)
    v, f = np.asarray(m.vertices) + UTM, np.asarray(m.faces)
    mesh = ReferenceMesh(v, f)
    p = UTM + rng.normal(0, 3.0, (5000, 3))
    whole = mesh.distances(p, max_distance_m=1.0)
    t = tiled_distances(_chunks(p, 700), len(p), tile_m=1.5, mesh=mesh,
                        max_distance_m=1.0, folder=tmp_path)
    np.testing.assert_array_equal(np.array(t.distance), whole.distance)
    assert t.tiles > 10
    t.close()
    assert list(tmp_path.iterdir()) == []              # nothing left behind


def test_tiled_api_refuses_bad_combinations():
    rng = np.random.default_rng(0)
    p = _tube(rng, 100, 2.0)
    with spill_cloud([p], 2.0, 0.1) as ref:
        with pytest.raises(CompareError, match="maximum distance"):
            tiled_distances([p], len(p), tile_m=2.0, reference=ref)
        with pytest.raises(CompareError, match="halo >= 0.5"):
            tiled_distances([p], len(p), tile_m=2.0, reference=ref, max_distance_m=0.5)
        with pytest.raises(CompareError, match="or a mesh, got both"):
            tiled_distances([p], len(p), tile_m=2.0, reference=ref, mesh=object(),
                            max_distance_m=0.1)
        with pytest.raises(CompareError, match="Expected 101"):
            tiled_distances([p], 101, tile_m=2.0, reference=ref, max_distance_m=0.1)


def _write_las(path, p):
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.scales, h.offsets = [0.001] * 3, UTM
    las = laspy.LasData(h)
    las.x, las.y, las.z = p.T
    las.intensity = np.arange(len(p)) % 60000
    las.write(path)


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    rng = np.random.default_rng(5)
    d = tmp_path_factory.mktemp("tiles")
    _write_las(d / "ref.las", _tube(rng, 60_000, 5.0))
    _write_las(d / "cmp.las", np.concatenate([_tube(rng, 40_000, 5.01),
                                              UTM + rng.uniform(0, 40, (500, 3))]))
    return d / "cmp.las", d / "ref.las"


def test_compare_tile_m_writes_the_same_files_here_and_on_two_workers(clouds, tmp_path):
    pytest.importorskip("distributed")
    cmp_, ref = clouds
    base = ["compare", str(cmp_), str(ref), "--max-dist", "0.2", "--split", "--quiet"]
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    assert main(base + ["-o", str(a)]) == 0
    assert main(base + ["--tile-m", "3", "-o", str(b)]) == 0
    assert main(base + ["--tile-m", "7", "--workers", "2", "-o", str(c)]) == 0
    for f in ("cmp_distance.laz", "stats.csv", "histogram.png"):
        assert (a / f).read_bytes() == (b / f).read_bytes() == (c / f).read_bytes(), f

    from tests.iofiles import report_body

    # the report's header states when it was computed: the one line that may differ
    assert report_body(a / "stats.md") == report_body(b / "stats.md") \
        == report_body(c / "stats.md")
    assert any("computed (UTC)" in ln for ln in (a / "stats.md").read_text().splitlines())
    # no spill or distance files left in the output folders
    assert sorted(p.name for p in b.iterdir()) == sorted(p.name for p in a.iterdir())
    assert sorted(p.name for p in c.iterdir()) == sorted(p.name for p in a.iterdir())
    # against an independent nearest-neighbour search on the files' coordinates
    from scipy.spatial import cKDTree

    got, r = laspy.read(c / "cmp_distance.laz"), laspy.read(ref)
    q = np.column_stack([got.x, got.y, got.z]) - UTM
    nn = cKDTree(np.column_stack([r.x, r.y, r.z]) - UTM).query(q)[0]
    np.testing.assert_allclose(got["distance"], np.minimum(nn, 0.2), rtol=1e-6, atol=1e-7)
    assert (np.asarray(got["distance"]) == np.float32(0.2)).sum() >= 400  # the far points
    np.testing.assert_array_equal(got.intensity, laspy.read(cmp_).intensity)


@pytest.mark.parametrize("extra, match", [
    (["--workers", "2"], "Expected --tile-m with --workers"),
    (["--tile-m", "5"], "Expected --max-dist with --tile-m"),
    (["--tile-m", "5", "--max-dist", "0.2", "--model", "plane"], "without --model"),
    (["--tile-m", "0", "--max-dist", "0.2"], "positive number of metres"),
])
def test_compare_tile_errors_are_one_line(clouds, tmp_path, capsys, extra, match):
    cmp_, ref = clouds
    assert main(["compare", str(cmp_), str(ref), "-o", str(tmp_path / "o")] + extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0], err
    assert not (tmp_path / "o").exists()


def test_a_halo_larger_than_the_tile_is_a_one_line_warning(clouds, tmp_path, capsys):
    """--max-dist given in mm by mistake (50 for 5 cm): still right, but slow; said."""
    cmp_, ref = clouds
    assert main(["compare", str(cmp_), str(ref), "--max-dist", "6", "--tile-m", "5",
                 "--quiet", "-o", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--max-dist 6 m is larger than --tile-m 5 m" in err[0], err
