"""``Scene.closest`` against brute force: every triangle tried, in NumPy.

``_brute`` spells the point–triangle test of Ericson 2005 (5.1.5) with the same
operations, in the same order, on the same numbers as the kernel (the scene's local
frame: vertices minus ``origin_offset``; a, ab = b - a, ac = c - a), and takes the
minimum of (squared distance, face row) over all faces of non-zero area: equal to the
BVH query bit for bit if the branch and bound never drops a triangle it should have
compared. ``tests.naive.naive_point_mesh`` (a different formula: foot of the
perpendicular or the nearest edge) checks the distances independently, to rounding.
"""

from __future__ import annotations

import warnings

import numba
import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from raytrace import ClosestPoints, RayError, Scene
from raytrace.shapes import tunnel_tube
from tests.naive import naive_point_mesh


def _brute(scene, points):
    """(distance, triangle, offset (n, 3), side) of every point, all faces tried."""
    local = np.asarray(scene.vertices, dtype=np.float64) - scene.origin_offset
    f = np.asarray(scene.faces)
    a = local[f[:, 0]]
    ab = local[f[:, 1]] - a
    ac = local[f[:, 2]] - a
    cr = np.cross(ab, ac)
    keep = np.flatnonzero((cr != 0).any(axis=1))      # zero-area faces are not in the BVH
    a, ab, ac = a[keep], ab[keep], ac[keep]
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3) - scene.origin_offset
    n = len(p)
    dist, tri, off, side = np.empty(n), np.empty(n, np.int64), np.empty((n, 3)), np.empty(n)

    def dot(u, w):
        return u[:, 0] * w[:, 0] + u[:, 1] * w[:, 1] + u[:, 2] * w[:, 2]

    for i in range(n):
        ap = p[i] - a
        d1, d2 = dot(ab, ap), dot(ac, ap)
        bp = ap - ab
        d3, d4 = dot(ab, bp), dot(ac, bp)
        vc = d1 * d4 - d3 * d2
        cp = ap - ac
        d5, d6 = dot(ab, cp), dot(ac, cp)
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        e43, e56 = d4 - d3, d5 - d6
        with np.errstate(divide="ignore", invalid="ignore"):
            v_ab = (d1 / (d1 - d3))[:, None]
            w_ac = (d2 / (d2 - d6))[:, None]
            w_bc = (e43 / (e43 + e56))[:, None]
            den = 1.0 / (va + vb + vc)
            v, w = (vb * den)[:, None], (vc * den)[:, None]
        regions = [(d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d4 <= d3),
                   (vc <= 0) & (d1 >= 0) & (d3 <= 0), (d6 >= 0) & (d5 <= d6),
                   (vb <= 0) & (d2 >= 0) & (d6 <= 0), (va <= 0) & (e43 >= 0) & (e56 >= 0)]
        offsets = [ap, bp, ap - v_ab * ab, cp, ap - w_ac * ac, bp - w_bc * (ac - ab)]
        e = ap - ab * v - ac * w                           # face region
        for r, o in zip(regions[::-1], offsets[::-1]):     # first region wins
            e = np.where(r[:, None], o, e)
        d2all = e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1] + e[:, 2] * e[:, 2]
        k = int(np.argmin(d2all))                          # first minimum: lowest row
        dist[i], tri[i], off[i] = np.sqrt(d2all[k]), keep[k], e[k]
        nrm = np.array([ab[k, 1] * ac[k, 2] - ab[k, 2] * ac[k, 1],
                        ab[k, 2] * ac[k, 0] - ab[k, 0] * ac[k, 2],
                        ab[k, 0] * ac[k, 1] - ab[k, 1] * ac[k, 0]])
        s = e[k, 0] * nrm[0] + e[k, 1] * nrm[1] + e[k, 2] * nrm[2]
        side[i] = -1.0 if s < 0 else 1.0
    return dist, tri, off, side


def _assert_brute(scene, points):
    got = scene.closest(points)
    d, t, e, s = _brute(scene, points)
    np.testing.assert_array_equal(got.triangle, t)
    np.testing.assert_array_equal(got.distance, d)
    np.testing.assert_array_equal(got.offset, e)
    np.testing.assert_array_equal(got.side, s)
    np.testing.assert_array_equal(got.points, np.asarray(points, np.float64).reshape(-1, 3) - e)
    return got


def _soup(rng, m, scale, offset=0.0):
    """m random triangles (a soup: each its own vertices) with zero-area ones (two equal
    vertices), an exact duplicate of triangle 0 at the end (a tie), and triangles that
    share an edge with their predecessor (ties on the shared edge)."""
    centres = rng.uniform(-scale, scale, (m, 1, 3))
    tris = centres + rng.normal(0, scale / 10, (m, 3, 3))
    k = rng.integers(0, m, m // 5)
    tris[k, 2] = tris[k, 1]
    j = rng.integers(1, m, m // 5) if m > 1 else np.zeros(0, np.int64)
    tris[j, :2] = tris[j - 1, :2]
    if m > 2:
        tris[-1] = tris[0]
    v = tris.reshape(-1, 3) + offset
    return v, np.arange(3 * m).reshape(-1, 3)


def _queries(rng, v, f, n, scale):
    """Random points, points on vertices, on edge midpoints and at face centroids (of
    faces of non-zero area)."""
    t = v[f]
    area = np.flatnonzero((np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]) != 0).any(axis=1))
    tri = t[rng.choice(area, 5)]
    return np.vstack([rng.uniform(-1.5 * scale, 1.5 * scale, (n, 3)) + v.mean(axis=0),
                      tri[:, 0], 0.5 * (tri[:, 0] + tri[:, 1]), tri.mean(axis=1)])


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(3, 300), st.integers(1, 150),
       st.sampled_from([1e-3, 1.0, 100.0]))
def test_equals_brute_force_on_triangle_soups(seed, m, n, scale):
    rng = np.random.default_rng(seed)
    v, f = _soup(rng, m, scale)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Dropped .* zero-area", UserWarning)
        scene = Scene(v, f)
    got = _assert_brute(scene, _queries(rng, v, f, n, scale))
    assert (got.distance[n:n + 5] == 0).all()             # points on vertices


def test_equals_brute_force_on_a_tunnel_and_agrees_with_the_naive_formula():
    v, f = tunnel_tube(3000, length_m=20.0, roughness_m=0.01, seed=2)
    scene = Scene(v, f)
    rng = np.random.default_rng(1)
    p = np.column_stack([rng.uniform(-2, 22, 300), rng.uniform(-4, 4, 300),
                         rng.uniform(-2, 5, 300)])
    got = _assert_brute(scene, p)
    d, _ = naive_point_mesh(p, v, f)
    np.testing.assert_allclose(got.distance, d, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(got.offset, axis=1), got.distance,
                               rtol=1e-15, atol=0)


def test_exact_ties_go_to_the_lower_face_row():
    # Two parallel squares at z = +1 and z = -1 (faces 0-3), queried on z = 0: every
    # point ties between a face above and one below; within a square, points on the
    # diagonal tie between its two faces.
    sq = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], dtype=np.float64)
    v = np.vstack([np.column_stack([sq, np.full(4, z)]) for z in (1.0, -1.0)])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]])
    p = np.array([[1.5, 0.5, 0.0], [0.5, 1.5, 0.0], [1.0, 1.0, 0.0], [1.0, 1.0, 0.5]])
    for perm in ([0, 1, 2, 3], [3, 2, 1, 0], [2, 0, 3, 1]):
        f = faces[perm]
        got = _assert_brute(Scene(v, f), p)
        rows = [int(np.flatnonzero((f == faces[k]).all(axis=1))[0]) for k in range(4)]
        # Expected: the lowest row among the faces at the least distance.
        want = [min(rows[0], rows[2]), min(rows[1], rows[3]),
                min(rows), min(rows[0], rows[1])]
        assert got.triangle.tolist() == want
        np.testing.assert_array_equal(got.distance, [1.0, 1.0, 1.0, 0.5])


def test_side_follows_the_face_normal():
    # Face (b - a) x (c - a) = +z: a point above is on the normal's side.
    scene = Scene([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    got = scene.closest([[0.2, 0.2, 0.5], [0.2, 0.2, -0.5], [0.2, 0.2, 0.0], [2, 2, -1]])
    assert got.side.tolist() == [1.0, -1.0, 1.0, -1.0]
    np.testing.assert_allclose(got.signed_distance[:3], [0.5, -0.5, 0.0], atol=1e-15)
    flipped = Scene([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 2, 1]])
    assert flipped.closest([0.2, 0.2, 0.5]).side.tolist() == [-1.0]


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(-10**6, 10**6), st.integers(4 * 10**6, 6 * 10**6),
       st.integers(-500, 2000))
def test_utm_offsets_change_nothing_where_exact(seed, east, north, up):
    # Dyadic coordinates (multiples of 1/8 m within 64 m) stay exact when shifted by
    # whole metres, so the local frame sees the very same numbers.
    rng = np.random.default_rng(seed)
    v = rng.integers(-256, 256, (120, 3)) / 8.0
    f = rng.integers(0, 120, (60, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    assume(len(f) > 0)
    p = rng.integers(-320, 320, (80, 3)) / 8.0
    shift = np.array([east, north, up], dtype=np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)      # collinear faces, if any
        a, b = Scene(v, f), Scene(v + shift, f)
    assume(np.array_equal(b.origin_offset - a.origin_offset, shift))
    near, far = a.closest(p), b.closest(p + shift)
    np.testing.assert_array_equal(far.triangle, near.triangle)
    np.testing.assert_array_equal(far.distance, near.distance)
    np.testing.assert_array_equal(far.offset, near.offset)
    np.testing.assert_array_equal(far.side, near.side)
    np.testing.assert_allclose(far.points - shift, near.points, rtol=0, atol=1e-8)


@pytest.fixture(scope="module")
def tunnel_scene():
    v, f = tunnel_tube(20_000, length_m=60.0, roughness_m=0.002, seed=3)
    return Scene(v, f)


def test_single_point_equals_a_one_row_batch(tunnel_scene):
    p = np.array([10.0, 0.3, 1.2])
    one, row = tunnel_scene.closest(p), tunnel_scene.closest(p[None, :])
    assert one.distance.shape == (1,) and one.points.shape == (1, 3)
    for name in ("distance", "triangle", "points", "offset", "side"):
        np.testing.assert_array_equal(getattr(one, name), getattr(row, name))
    assert isinstance(one, ClosestPoints) and len(one) == 1


def test_threads_batches_and_order_do_not_change_the_answer(tunnel_scene):
    rng = np.random.default_rng(7)
    # More points than config.ORDER_MIN_RAYS: scattered ones are queried in Morton order.
    p = np.column_stack([rng.uniform(-5, 65, 70_000), rng.uniform(-5, 5, 70_000),
                         rng.uniform(-3, 6, 70_000)])
    whole = tunnel_scene.closest(p)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = tunnel_scene.closest(p)
    finally:
        numba.set_num_threads(threads)
    parts = [tunnel_scene.closest(p[a:a + 777]) for a in range(0, len(p), 777)]
    for name in ("distance", "triangle", "offset", "side"):
        np.testing.assert_array_equal(getattr(one, name), getattr(whole, name))
        np.testing.assert_array_equal(np.concatenate([getattr(x, name) for x in parts]),
                                      getattr(whole, name))
    sample = rng.choice(len(p), 200, replace=False)
    d, t, e, s = _brute(tunnel_scene, p[sample])
    np.testing.assert_array_equal(whole.triangle[sample], t)
    np.testing.assert_array_equal(whole.distance[sample], d)


def test_a_loaded_scene_answers_the_same(tunnel_scene, tmp_path):
    p = np.random.default_rng(2).uniform(-3, 6, (500, 3)) + [30.0, 0.0, 0.0]
    path = tunnel_scene.save(tmp_path / "s.npz")
    want = tunnel_scene.closest(p)
    for mmap in (False, True):
        got = Scene.load(path, mmap=mmap).closest(p)
        np.testing.assert_array_equal(got.triangle, want.triangle)
        np.testing.assert_array_equal(got.distance, want.distance)


def test_empty_input_gives_empty_results(tunnel_scene):
    got = tunnel_scene.closest(np.empty((0, 3)))
    assert got.distance.shape == (0,) and got.distance.dtype == np.float64
    assert got.triangle.shape == (0,) and got.triangle.dtype == np.int64
    assert got.points.shape == (0, 3) and got.side.shape == (0,)


@pytest.mark.parametrize("bad, match", [
    (np.zeros((4, 2)), r"Expected `points` to have shape \(n, 3\) or \(3,\), got \(4, 2\)"),
    ([[0.0, np.nan, 1.0]], r"Expected finite coordinates in `points`, got NaN or inf"),
    ([[0.0, 0.0, np.inf]], r"Expected finite coordinates in `points`"),
    ("abc", r"Expected `points` as numbers"),
])
def test_bad_points_are_refused(tunnel_scene, bad, match):
    with pytest.raises(RayError, match=match):
        tunnel_scene.closest(bad)
