"""Scene behaviour: georeferenced precision, thread determinism, save/load, any-hit,
intervals, file loading, validation of bad input."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from raytrace import MeshError, RayError, Scene, SceneFileError
from raytrace.shapes import tunnel_tube


@pytest.fixture(scope="module")
def small_tunnel():
    v, f = tunnel_tube(20_000, length_m=60.0, roughness_m=0.002, seed=3)
    return v, f


def _rays_in(rng, n, length_m):
    """n rays with origins inside a tunnel_tube of the given length, random directions."""
    o = np.stack([rng.uniform(1, length_m - 1, n), rng.uniform(-1, 1, n),
                  rng.uniform(0.3, 2.4, n)], axis=1)
    return o, rng.standard_normal((n, 3))


def _station_rays(origin, n=40_000, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((n, 3))
    return origin, d


def test_utm_coordinates_hit_like_local(small_tunnel):
    """A tunnel at eastings ~450 000 m, northings ~5 350 000 m gives the hits of the same
    tunnel near the origin to 0.1 mm (we require 1e-6 m)."""
    v, f = small_tunnel
    shift = np.array([451_234.567, 5_352_345.678, 312.345])
    local = Scene(v, f)
    utm = Scene(v + shift, f)
    o, d = _station_rays(np.array([30.0, 0.2, 1.6]))
    a = local.cast(o, d)
    b = utm.cast(o + shift, d)
    assert a.hit.mean() > 0.99
    np.testing.assert_array_equal(a.hit, b.hit)
    np.testing.assert_allclose(b.t, a.t, rtol=0, atol=1e-6)
    same = a.triangle == b.triangle
    assert same.mean() > 0.999  # the rest are edge ties at equal distance
    np.testing.assert_allclose(b.points[a.hit] - shift, a.points[a.hit], rtol=0, atol=1e-6)
    # Naive float32 storage would be off by up to ~0.5 m at northing 5.35e6: the local
    # origin is what keeps it exact.
    assert np.abs(utm.origin_offset - np.round(shift + np.array([30.0, 0.0, 1.4]))).max() < 5


def test_thread_count_does_not_change_results(small_tunnel):
    v, f = small_tunnel
    scene = Scene(v, f)
    o, d = _rays_in(np.random.default_rng(5), 50_000, 60.0)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = scene.cast(o, d)
        occ_a = scene.occluded(o, d, t_max=2.0)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        b = scene.cast(o, d)
        occ_b = scene.occluded(o, d, t_max=2.0)
    finally:
        numba.set_num_threads(before)
    for name in ("t", "triangle", "u", "v"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(occ_a, occ_b)


@pytest.mark.parametrize("mmap", [False, True])
def test_save_load_round_trip(small_tunnel, tmp_path, mmap):
    v, f = small_tunnel
    scene = Scene(v + np.array([450_000.0, 5_350_000.0, 0.0]), f)
    path = scene.save(tmp_path / "tunnel.bvh.npz")
    assert [p.name for p in tmp_path.iterdir()] == ["tunnel.bvh.npz"]  # no temp left
    again = Scene.load(path, mmap=mmap)
    # Mapped: the arrays are views of the file, not copies read from it.
    assert all(isinstance(a, np.memmap) == mmap
               for a in (again._nodes, again._tris, again._ids))
    np.testing.assert_array_equal(again.vertices, scene.vertices)
    np.testing.assert_array_equal(again.faces, scene.faces)
    o = np.array([450_030.0, 5_350_000.0, 1.5])
    d = np.random.default_rng(2).standard_normal((20_000, 3))
    a, b = scene.cast(o, d), again.cast(o, d)
    for name in ("t", "triangle", "u", "v"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert again.stats == scene.stats
    np.testing.assert_array_equal(again.origin_offset, scene.origin_offset)


def test_load_rejects_bad_files(tmp_path):
    with pytest.raises(SceneFileError, match="no file"):
        Scene.load(tmp_path / "missing.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(SceneFileError, match="could not be read"):
        Scene.load(bad)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(SceneFileError, match="could not be read"):
        Scene.load(tmp_path / "other.npz")
    # A compressed copy of a real scene file reads, but cannot be mapped.
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    saved = Scene(v, np.array([[0, 1, 2]])).save(tmp_path / "s.npz")
    with np.load(saved) as z:
        np.savez_compressed(tmp_path / "deflated.npz", **{k: z[k] for k in z.files})
    assert Scene.load(tmp_path / "deflated.npz").faces.shape == (1, 3)
    with pytest.raises(SceneFileError, match="uncompressed"):
        Scene.load(tmp_path / "deflated.npz", mmap=True)


def test_occluded_matches_cast(small_tunnel):
    v, f = small_tunnel
    scene = Scene(v, f)
    rng = np.random.default_rng(8)
    o, d = _rays_in(rng, 30_000, 60.0)
    t_max = rng.uniform(0, 4, 30_000)
    h = scene.cast(o, d)
    occ = scene.occluded(o, d, t_max=t_max)
    np.testing.assert_array_equal(occ, h.t <= t_max)


def test_interval_and_broadcasting():
    v = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1], [0, 0, 2], [1, 0, 2], [0, 1, 2.0]])
    f = np.array([[0, 1, 2], [3, 4, 5]])
    scene = Scene(v, f)
    d = np.array([[0, 0, 2.0], [0, 0, 1.0], [0, 0, 0.5]])  # not unit: t is along unit d
    h = scene.cast([0.1, 0.1, 0.0], d)
    np.testing.assert_array_equal(h.t, [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(h.triangle, [0, 0, 0])
    h = scene.cast([0.1, 0.1, 0.0], d, t_min=np.array([0.0, 1.5, 2.5]))
    np.testing.assert_array_equal(h.triangle, [0, 1, -1])
    h = scene.cast([0.1, 0.1, 0.0], d, t_max=0.99)
    assert not h.hit.any() and np.isinf(h.t).all()
    # Both faces are hit: from above the second plane looks at its back face.
    h = scene.cast([0.1, 0.1, 3.0], [[0, 0, -1.0]])
    assert h.triangle[0] == 1 and h.t[0] == 1.0 and h.normals[0, 2] == 1.0
    # Empty input gives empty, typed output.
    e = scene.cast(np.zeros(3), np.zeros((0, 3)))
    assert e.t.shape == (0,) and e.triangle.dtype == np.int64


def test_tie_goes_to_lower_index():
    # Two coincident triangles listed in both orders: the lower input index wins.
    v = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1.0]])
    scene = Scene(v, np.array([[0, 1, 2], [0, 2, 1], [1, 2, 0]]))
    h = scene.cast([0.2, 0.2, 0.0], np.tile([0, 0, 1.0], (100, 1)))
    assert (h.triangle == 0).all()


def test_degenerate_triangles_dropped_with_warning():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], dtype=float)
    f = np.array([[0, 1, 2], [0, 1, 3], [1, 1, 2]])  # two zero-area faces
    with pytest.warns(UserWarning, match="Dropped 2 zero-area"):
        scene = Scene(v, f)
    assert scene.n_triangles == 1
    h = scene.cast([0.2, 0.2, 1.0], [[0, 0, -1.0]])
    assert h.triangle[0] == 0
    with pytest.raises(MeshError, match="non-zero area"):
        Scene(v, f[1:])


@pytest.mark.parametrize("vertices, faces, match", [
    (np.zeros((0, 3)), np.zeros((0, 3), int), "empty"),
    (np.zeros((4, 2)), [[0, 1, 2]], r"shape \(n, 3\), got \(4, 2\)"),
    ([[0, 0, 0], [1, 0, np.nan], [0, 1, 0]], [[0, 1, 2]], r"NaN/inf at vertex index\(es\) 1"),
    ([[0, 0, 0], [1, 0, np.inf], [0, 1, 0]], [[0, 1, 2]], "NaN/inf"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3], [0, 1, 2], [-1, 0, 1]],
     r"out-of-range indices in face\(s\) 0, 2"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1]], r"shape \(m, 3\)"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.zeros((0, 3), int), "empty"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2.5]], "integer"),
])
def test_bad_meshes(vertices, faces, match):
    with pytest.raises(MeshError, match=match):
        Scene(vertices, faces)


@pytest.mark.parametrize("kwargs", [dict(sah_bins=1), dict(max_leaf_size=0),
                                    dict(c_trav=0.0), dict(c_isect=-1.0)])
def test_bad_build_constants(kwargs):
    with pytest.raises(ValueError, match="sah_bins"):
        Scene([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], **kwargs)


def test_bad_rays():
    scene = Scene([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    with pytest.raises(RayError, match=r"zero length at row\(s\) 1"):
        scene.cast(np.zeros(3), [[0, 0, 1], [0, 0, 0]])
    with pytest.raises(RayError, match=r"`directions` to have shape \(n, 3\), got \(2, 2\)"):
        scene.cast(np.zeros(3), np.ones((2, 2)))
    with pytest.raises(RayError, match="`origins` to have shape"):
        scene.cast(np.zeros((3, 3)), np.ones((2, 3)))
    with pytest.raises(RayError, match="NaN/inf at row"):
        scene.cast([np.nan, 0, 0], np.ones((2, 3)))
    with pytest.raises(RayError, match="NaN/inf at row"):
        scene.occluded(np.zeros(3), [[np.inf, 0, 1]])
    with pytest.raises(RayError, match="t_min"):
        scene.cast(np.zeros(3), np.ones((2, 3)), t_min=-1.0)
    with pytest.raises(RayError, match="t_max"):
        scene.cast(np.zeros(3), np.ones((2, 3)), t_max=np.ones(3))
    # Errors are ValueErrors too, for generic callers.
    with pytest.raises(ValueError):
        scene.cast(np.zeros(3), [[0, 0, 0]])


def test_stats_are_consistent(small_tunnel):
    v, f = small_tunnel
    s = Scene(v, f).stats
    assert s["triangles"] == len(f)
    assert s["leaves"] * s["mean_leaf_size"] == pytest.approx(len(f))
    assert s["nodes"] == 2 * s["leaves"] - 1  # a binary tree
    assert s["max_depth"] >= np.log2(s["leaves"])
    assert s["sah_cost"] > 1.0 and s["build_seconds"] > 0
    assert set(s) >= {"triangles", "nodes", "leaves", "max_depth", "mean_leaf_size",
                      "sah_cost", "build_seconds"}


def test_large_scattered_batches_are_ordered_without_changing_results(small_tunnel,
                                                                      monkeypatch):
    """Batches above ORDER_MIN_RAYS are cast in Morton order of their origins; the
    answer (and any-hit) must be the same as in input order."""
    from raytrace import config

    v, f = small_tunnel
    scene = Scene(v, f)
    rng = np.random.default_rng(12)
    n = 100_000
    o = np.stack([rng.uniform(-5, 65, n), rng.uniform(-2, 2, n), rng.uniform(-1, 4, n)], 1)
    d = rng.standard_normal((n, 3))
    t_max = rng.uniform(0.5, 30, n)
    assert n >= config.ORDER_MIN_RAYS
    order = scene._ray_order(o - scene.origin_offset)
    assert sorted(order.tolist()) == list(range(n)) and (order != np.arange(n)).any()
    a = scene.cast(o, d, t_max=t_max)
    occ_a = scene.occluded(o, d, t_max=t_max)
    monkeypatch.setattr(config, "ORDER_MIN_RAYS", 10**9)
    assert len(scene._ray_order(o)) == 0
    b = scene.cast(o, d, t_max=t_max)
    occ_b = scene.occluded(o, d, t_max=t_max)
    for name in ("t", "triangle", "u", "v"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(occ_a, occ_b)


def test_build_is_identical_for_any_thread_count():
    """The parallel parts of the build (the breadth-first top phase, binned and partitioned in parallel work items,
    subtrees) must give the same tree as a one-thread build, bit for bit."""
    v, f = tunnel_tube(150_000, length_m=100.0, roughness_m=0.002, seed=6)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = Scene(v, f)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        b = Scene(v, f)
    finally:
        numba.set_num_threads(before)
    np.testing.assert_array_equal(a._nodes.view(np.int32), b._nodes.view(np.int32))
    np.testing.assert_array_equal(a._tris, b._tris)
    np.testing.assert_array_equal(a._ids, b._ids)


def test_set_threads_validates():
    from raytrace import set_threads, threads

    before = threads()
    try:
        assert set_threads(1) == 1 and threads() == 1
        with pytest.raises(ValueError, match="thread count between 1 and"):
            set_threads(0)
        with pytest.raises(ValueError, match="thread count between 1 and"):
            set_threads(numba.config.NUMBA_NUM_THREADS + 1)
    finally:
        set_threads(before)
