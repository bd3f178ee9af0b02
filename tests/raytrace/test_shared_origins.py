"""Shared origins in an (n, 3) array (issue 16): runs of equal rows are found, routed to
the per-origin cube map, and give bit-identical answers to the BVH and to a (3,) origin;
a coherent batch keeps its own order; cube-map footprints stay conservative where
triangle vertices lie exactly on cube-face borders."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene, config
from raytrace._kernels.order import is_coherent, origin_runs
from raytrace.shapes import tunnel_tube

FIELDS = ("t", "triangle", "u", "v")


def _assert_same(a, b):
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def _naive_runs(rows, min_len):
    """Runs of equal consecutive rows, by a plain Python walk over tuples."""
    out, a = [], 0
    keys = [tuple(r) for r in rows]
    for i in range(1, len(keys) + 1):
        if i == len(keys) or keys[i] != keys[a]:
            if i - a >= min_len:
                out.append((a, i))
            a = i
    return out


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 3), min_size=0, max_size=60), st.integers(1, 6))
def test_origin_runs_match_a_naive_walk(labels, min_len):
    table = np.array([[0.0, 0.0, 0.0], [-0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.5]])
    rows = table[np.asarray(labels, dtype=np.int64)] if labels else np.empty((0, 3))
    bits = np.ascontiguousarray(rows).view(np.int64)
    got = [tuple(r) for r in origin_runs(bits, min_len).tolist()]
    # Bit patterns, not values: -0.0 and 0.0 are different origins here.
    assert got == _naive_runs(bits.tolist(), min_len)


def test_is_coherent_counts_jumps():
    path = np.zeros((1000, 3))
    path[:, 0] = np.linspace(0.0, 1.0, 1000)        # steps of 1 mm
    assert is_coherent(path, 0.01, 0)
    jumpy = path.copy()
    jumpy[::100, 2] += 1.0                            # 10 rows off the path: 19 jumps
    assert is_coherent(jumpy, 0.01, 19) and not is_coherent(jumpy, 0.01, 18)


@pytest.fixture(scope="module")
def tunnel():
    v, f = tunnel_tube(20_000, length_m=60.0, roughness_m=0.003, seed=4)
    return Scene(v, f)


def _dirs(n, seed):
    return np.random.default_rng(seed).standard_normal((n, 3))


def test_station_as_array_equals_single_origin_and_uses_the_cube_map(tunnel):
    o = np.array([30.0, 0.1, 1.5])
    d = _dirs(30_000, 1)                              # > 0.5 rays per triangle
    assert len(d) >= config.CUBEMAP_MIN_RAYS_PER_TRI * tunnel.n_triangles
    ref = tunnel.cast(o, d, method="bvh")
    tunnel._view_cache = None
    _assert_same(tunnel.cast(np.repeat(o[None], len(d), axis=0), d), ref)
    key = (o - tunnel.origin_offset)[None].tobytes()
    assert tunnel._view_cache is not None and tunnel._view_cache[0] == key
    _assert_same(tunnel.cast(o, d), ref)
    # method="cubemap" on an all-equal array, below the "auto" threshold.
    tunnel._view_cache = None
    few = d[:500]
    _assert_same(tunnel.cast(np.repeat(o[None], 500, axis=0), few, method="cubemap"),
                 tunnel.cast(o, few, method="bvh"))
    assert tunnel._view_cache is not None and tunnel._view_cache[0] == key


def test_runs_of_origins_mixed_with_scattered_ones_match_the_bvh(tunnel, monkeypatch):
    """Two long runs (each to its own cube map) between scattered rows (to the BVH),
    with per-ray limits, at one and at all threads: all equal to the BVH."""
    monkeypatch.setattr(config, "CUBEMAP_MIN_RAYS_PER_TRI", 0.2)   # runs >= 4,000 rays
    rng = np.random.default_rng(2)
    n = 20_000
    o = np.stack([rng.uniform(2, 58, n), rng.uniform(-1, 1, n), rng.uniform(0.3, 2.4, n)], 1)
    o[3_000:9_000] = [20.0, 0.0, 1.2]
    o[12_000:17_000] = [45.0, -0.3, 2.0]
    d = _dirs(n, 3)
    t_max = rng.uniform(0.5, 40, n)
    ref = tunnel.cast(o, d, t_max=t_max, method="bvh")
    before = numba.get_num_threads()
    try:
        for threads in (1, numba.config.NUMBA_NUM_THREADS):
            numba.set_num_threads(threads)
            tunnel._view_cache = None
            _assert_same(tunnel.cast(o, d, t_max=t_max), ref)
            assert tunnel._view_cache is not None                # a run used its map
    finally:
        numba.set_num_threads(before)


def test_coherent_batches_keep_their_order_and_answer(tunnel):
    """A drive-like batch (origins creeping along the tunnel) is not re-sorted; the
    answer equals the BVH's in any order."""
    n = config.ORDER_MIN_RAYS + 1000
    o = np.zeros((n, 3))
    o[:, 0] = np.linspace(10.0, 11.0, n)
    o[:, 2] = 1.0
    assert len(tunnel._ray_order(o - tunnel.origin_offset)) == 0
    d = _dirs(n, 4)
    perm = np.random.default_rng(5).permutation(n)
    assert len(tunnel._ray_order(o[perm] - tunnel.origin_offset)) == n   # scattered
    a = tunnel.cast(o, d)
    b = tunnel.cast(o[perm], d[perm])
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name)[perm], getattr(b, name))


def test_cube_map_is_exact_with_vertices_on_face_borders():
    """Vertices exactly on the cube-face border planes |y| = x seen from the origin
    (the footprints' fast path must leave such triangles to the clipping path): rays
    at every vertex and at random agree with the BVH."""
    k = 9
    y, z = np.meshgrid(np.linspace(-2.0, 2.0, k), np.linspace(-2.0, 2.0, k), indexing="ij")
    verts = []
    for x in (1.0, 2.0):                              # two walls, |y| = x and |z| = x on grid
        verts.append(np.stack([np.full(k * k, x), y.ravel(), z.ravel()], 1))
    v = np.concatenate(verts)
    faces = []
    for w in range(2):
        base = w * k * k
        for i in range(k - 1):
            for j in range(k - 1):
                a = base + i * k + j
                faces += [[a, a + k, a + 1], [a + 1, a + k, a + k + 1]]
    scene = Scene(v, np.array(faces))
    rng = np.random.default_rng(6)
    d = np.concatenate([v, rng.standard_normal((20_000, 3)),
                        v + rng.normal(0, 1e-9, v.shape)])
    for origin in ([0.0, 0.0, 0.0], [0.5, 0.5, -0.5]):
        scene._view_cache = None
        _assert_same(scene.cast(origin, d, method="cubemap"),
                     scene.cast(origin, d, method="bvh"))


def test_origin_on_a_triangle_edge_in_its_plane_hits_at_zero():
    """Regression (found by the brute-force property test once (n, 3) origins reached
    the cube map): an origin on a triangle's edge, in its plane, with a ray leaving the
    plane, hits at t = 0; the cube map must list the triangle for that direction."""
    v = np.array([[3.75, 3.75, 3.75], [3.75, 3.75, -1.6875], [1.0, 3.75, 3.75]])
    scene = Scene(v, np.array([[0, 1, 2]]))
    d = np.concatenate([[[-1.0, -1.0, -1.0]], _dirs(2000, 7)])
    for origin in ([3.75, 3.75, 0.0], [3.75, 3.75, 3.75], [2.0, 3.75, 3.0]):
        ref = scene.cast(origin, d, method="bvh")
        assert ref.t[0] == 0.0
        scene._view_cache = None
        _assert_same(scene.cast(origin, d, method="cubemap"), ref)
        _assert_same(scene.cast(np.repeat([origin], len(d), axis=0), d), ref)


def test_rows_of_a_rolling_shutter_on_a_small_mesh_build_no_map_each():
    """A rolling-shutter frame's rows (one origin per 1,920-ray row) on a small mesh of
    large triangles: a whole map per row cost more than the row (13 s a frame on a
    3,776-face artist mesh), so the rows walk the BVH (no map kept); a run as long as
    the map's cells gets one. Answers equal the BVH's either way."""
    v, f = tunnel_tube(2_000, length_m=20.0, seed=1)
    scene = Scene(v, f)
    side = scene._map_side()
    assert 0.5 * scene.n_triangles < 1_920 < 0.5 * 6 * side ** 2   # the case in point
    rows = np.repeat(np.stack([np.linspace(5.0, 5.06, 4), np.zeros(4),
                               np.full(4, 1.2)], 1), 1_920, axis=0)
    d = _dirs(len(rows), 5)
    ref = scene.cast(rows, d, method="bvh")
    _assert_same(scene.cast(rows, d), ref)
    assert scene._view_cache is None
    n = int(np.ceil(0.5 * 6 * side ** 2))
    o = np.array([10.0, 0.2, 1.0])
    d = _dirs(n, 6)
    _assert_same(scene.cast(np.repeat(o[None], n, axis=0), d), scene.cast(o, d, method="bvh"))
    assert scene._view_cache is not None
