"""M3C2 in tiles with a halo (survey.cluster.tiles, survey.cluster.m3c2_tiles; issues 17
and 19): the spill puts every point in its tile and exactly the halo's points beside
it (brute force over every tile), and M3C2 tile by tile gives the same bytes as M3C2 on
the whole epochs, in the library, through the command, and on a 2-worker LocalCluster.
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from survey.analysis.m3c2 import M3C2, M3C2Params, subsample
from survey.cluster.m3c2_tiles import halo_of, iter_subsample, m3c2_files
from survey.cluster.tiles import TileSpill
from survey.errors import ClusterError, CompareError

UTM = np.array([500_000.3, 5_400_000.7, 312.0])


def _brute_tiles(spill, p, halo):
    """{key: rows} by testing every point against every tile's own and grown box."""
    own = spill.own(p)
    out = {}
    lo_i, hi_i = own.min(0) - int(np.ceil(halo / spill.tile_m)) - 2, \
        own.max(0) + int(np.ceil(halo / spill.tile_m)) + 2
    for i in range(lo_i[0], hi_i[0] + 1):
        for j in range(lo_i[1], hi_i[1] + 1):
            b = spill.box((i, j))
            grown = ((p[:, 0] >= b[0, 0] - halo) & (p[:, 0] <= b[1, 0] + halo)
                     & (p[:, 1] >= b[0, 1] - halo) & (p[:, 1] <= b[1, 1] + halo))
            rows = np.flatnonzero(grown | ((own[:, 0] == i) & (own[:, 1] == j)))
            if rows.size:
                out[(i, j)] = rows
    return out


# ---------------------------------------------------------------------- the spill
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), tile=st.floats(0.5, 5.0),
       halo=st.sampled_from([0.0, 0.1, 0.7, 2.5]), n=st.integers(1, 300),
       chunk=st.integers(20, 150))
def test_spill_holds_each_tile_and_exactly_its_halo_in_input_order(seed, tile, halo, n,
                                                                   chunk):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-6, 6, (n, 3)) + UTM
    p[: n // 4, 0] = np.round(p[: n // 4, 0] / tile) * tile     # points on tile edges
    extra = rng.standard_normal((n, 2))
    with TileSpill(tile, halo, extra=2, anchor=UTM[:2]) as s:
        for a in range(0, n, chunk):
            s.add(p[a:a + chunk], index=np.arange(a, min(n, a + chunk)),
                  extra=extra[a:a + chunk])
        want = _brute_tiles(s, p, halo)
        assert s.keys() == sorted(want)
        owned = 0
        for k in s.keys():
            d = s.read(k)
            assert np.array_equal(d.index, want[k])          # ascending: input order
            assert np.array_equal(d.xyz, p[want[k]]) and np.array_equal(d.extra,
                                                                        extra[want[k]])
            assert s.size(k) == len(d)
            owned += int(np.all(s.own(d.xyz) == k, axis=1).sum())
        assert owned == n                                    # one own tile per point
        assert s.count == n
        assert np.array_equal(s.bounds, np.stack([p.min(0), p.max(0)]))
        folder = s.folder
    assert not folder.exists()


def test_spill_refuses_bad_input(tmp_path):
    with pytest.raises(ClusterError, match="positive finite `tile_m`"):
        TileSpill(0.0)
    with pytest.raises(ClusterError, match="non-negative finite `halo_m`"):
        TileSpill(1.0, -0.1)
    with pytest.raises(ClusterError, match="existing folder"):
        TileSpill(1.0, folder=tmp_path / "none")
    with TileSpill(1.0, folder=tmp_path) as s:
        assert s.folder.parent == tmp_path
        with pytest.raises(ClusterError, match=r"shape \(n, 3\)"):
            s.add(np.zeros((4, 2)))
        s.add(np.zeros((2, 3)), index=[0, 1])
        with pytest.raises(ClusterError, match="on every call or on none"):
            s.add(np.zeros((2, 3)))
        with pytest.raises(ClusterError, match="no `extra`"):
            s.add(np.zeros((2, 3)), index=[2, 3], extra=np.zeros((2, 1)))
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------- M3C2 in tiles
def _surface(rng, n, shift=0.0, size=4.0):
    xy = rng.uniform(0, size, (n, 2))
    z = shift + 0.003 * rng.standard_normal(n) + 0.05 * np.sin(2 * xy[:, 0])
    return np.c_[xy, z] + UTM


@pytest.fixture(scope="module")
def epochs():
    rng = np.random.default_rng(3)
    return _surface(rng, 12_000), _surface(rng, 12_000, shift=0.005)


def _same_bytes(a, b):
    for f in fields(a):
        x, y = np.asarray(getattr(a, f.name)), np.asarray(getattr(b, f.name))
        assert x.dtype == y.dtype and x.shape == y.shape, f.name
        assert x.tobytes() == y.tobytes(), f.name


@pytest.mark.parametrize("robust", [False, True])
@pytest.mark.parametrize("tile_m", [1.7, 0.45])
def test_tiled_m3c2_is_the_untiled_to_the_last_bit(epochs, tile_m, robust):
    """Two tile sizes, one smaller than the halo (0.45 < 0.55 m): every field equal
    byte for byte to M3C2 on the whole epochs, at UTM coordinates."""
    e1, e2 = epochs
    prm = M3C2Params(0.2, 0.5, (0.25, 0.4), 0.001, robust)
    assert halo_of(prm) > 0.45
    core = e1[::40] + np.random.default_rng(1).normal(0, 0.01, (300, 3))
    want = M3C2(e1, e2, prm).compute(core)
    assert np.isfinite(want.distance).mean() > 0.9
    with m3c2_files(e1, e2, core, prm, tile_m=tile_m, chunk=5_000) as store:
        assert store.xyz(0, len(store)).tobytes() == core.tobytes()
        _same_bytes(store.result(0, len(store)), want)
        chunked = [r for _, r in store.chunks(77)]
        assert sum(len(r) for r in chunked) == len(core)


def test_tiled_core_spacing_is_subsample_streamed(epochs):
    e1, e2 = epochs
    prm = M3C2Params(0.2, 0.3, (0.3,))
    core = subsample(e1, 0.3)
    parts = list(iter_subsample((e1[a:a + 999] for a in range(0, len(e1), 999)), 0.3,
                                e1.min(0), e1.max(0)))
    assert np.concatenate(parts).tobytes() == core.tobytes()
    want = M3C2(e1, e2, prm).compute(core, orientation=(0.0, 0.0, -1.0))
    with m3c2_files(e1, e2, 0.3, prm, tile_m=1.3, orientation=(0, 0, -1),
                    chunk=3_000) as store:
        _same_bytes(store.result(0, len(store)), want)


def test_tiled_m3c2_refuses_bad_input(epochs, tmp_path):
    e1, e2 = epochs
    prm = M3C2Params(0.2, 0.3, (0.3,))
    for bad in (0.0, -1.0, float("nan"), "x"):
        with pytest.raises(CompareError, match="positive finite `tile_m`"):
            m3c2_files(e1, e2, None, prm, tile_m=bad)
    with pytest.raises(CompareError, match="normal_radii_m"):
        m3c2_files(e1, e2, None, M3C2Params(0.2, 0.3), tile_m=1.0)
    with pytest.raises(CompareError, match="different coordinate systems"):
        m3c2_files(e1, e2 - UTM, None, prm, tile_m=1.0, spill_dir=tmp_path)
    with pytest.raises(CompareError, match="`epoch2` with points"):
        m3c2_files(e1, np.empty((0, 3)), None, prm, tile_m=1.0, spill_dir=tmp_path)
    assert list(tmp_path.iterdir()) == []          # nothing left behind


# ---------------------------------------------------------------------- the command
@pytest.fixture(scope="module")
def epoch_files(tmp_path_factory, epochs):
    from sensors.io.cloudmap import write_points_las

    d = tmp_path_factory.mktemp("m3c2tiles")
    e1, e2 = epochs
    write_points_las(d / "e1.las", e1)
    write_points_las(d / "e2.las", e2)
    write_points_las(d / "core.las", e1[::30])
    return d


ARGS = ["--cyl-radius", "0.2", "--max-depth", "0.4", "--normal-radii", "0.25,0.4",
        "--quiet"]


def _las_fields(path):
    import laspy

    las = laspy.read(path)
    return {n: np.asarray(las[n]) for n in las.point_format.dimension_names}


def _assert_same_las(a, b):
    fa, fb = _las_fields(a), _las_fields(b)
    assert sorted(fa) == sorted(fb)
    for n in fa:
        assert fa[n].tobytes() == fb[n].tobytes(), n
    assert "distance" in fa and np.isfinite(fa["distance"]).mean() > 0.9


@pytest.mark.parametrize("core", [["--core-spacing", "0.25"], ["--core", "core.las"]])
def test_cli_tiles_write_the_same_file(epoch_files, tmp_path, core):
    from survey.cli.main import main

    d = epoch_files
    core = [str(d / c) if c.endswith(".las") else c for c in core]
    base = ["m3c2", str(d / "e1.las"), str(d / "e2.las"), *core, *ARGS]
    assert main(base + ["-o", str(tmp_path / "a.las")]) == 0
    assert main(base + ["--tile-m", "1.5", "-o", str(tmp_path / "b.las")]) == 0
    _assert_same_las(tmp_path / "a.las", tmp_path / "b.las")
    ja, jb = ((tmp_path / f"{s}.json").read_text() for s in "ab")
    assert ja == jb
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".tunnelsim")]


def test_cli_tiles_on_two_workers_write_the_same_file(epoch_files, tmp_path):
    pytest.importorskip("distributed")
    from survey.cli.main import main

    d = epoch_files
    base = ["m3c2", str(d / "e1.las"), str(d / "e2.las"), "--core-spacing", "0.25",
            *ARGS]
    assert main(base + ["-o", str(tmp_path / "a.las")]) == 0
    assert main(base + ["--tile-m", "1.5", "--workers", "2", "-o",
                        str(tmp_path / "b.las")]) == 0
    _assert_same_las(tmp_path / "a.las", tmp_path / "b.las")


@pytest.mark.parametrize("extra,match", [
    (["--workers", "2"], "Expected --tile-m with --workers or --scheduler"),
    (["--tile-m", "0"], "Expected a positive --tile-m"),
    (["--tile-m", "-2"], "Expected a positive --tile-m"),
])
def test_cli_tile_errors_are_one_line(epoch_files, tmp_path, capsys, extra, match):
    from survey.cli.main import main

    d = epoch_files
    out = tmp_path / "x.las"
    assert main(["m3c2", str(d / "e1.las"), str(d / "e2.las"), *ARGS, *extra, "-o",
                 str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tunnelsim: error: ") and match in err[0]
    assert not out.exists()


def test_tiled_m3c2_towards_the_axis_is_the_untiled(epochs):
    """Normals oriented towards a tunnel axis (a picklable function of the core points,
    as workers receive it): the same bytes as untiled."""
    import pickle
    from functools import partial

    from survey.analysis.m3c2 import towards_axis
    from survey.world.alignment import Alignment, straight

    e1, e2 = epochs
    al = Alignment([straight(10.0)], start_xy=UTM[:2] - 1.0, heading_rad=0.3,
                   profile=((0.0, UTM[2]),))
    fn = pickle.loads(pickle.dumps(partial(towards_axis, al, centre=(0.5, 2.0))))
    prm = M3C2Params(0.2, 0.3, (0.3,))
    core = e1[::60]
    want = M3C2(e1, e2, prm).compute(core, towards=fn(core))
    with m3c2_files(e1, e2, core, prm, tile_m=1.9, towards=fn) as store:
        _same_bytes(store.result(0, len(store)), want)
    assert np.nanmedian(want.normal[:, 2]) > 0.9          # up, towards the axis above
