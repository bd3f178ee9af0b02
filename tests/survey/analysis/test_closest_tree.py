"""The nearest-triangle tree (survey._kernels.closest_bvh) against brute force: the
same triangle (ties to the lower index) and the same closest point, bit for bit, on
random triangle soups with degenerate and duplicated triangles, for any leaf order."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from survey._kernels.closest import nearest_triangles
from survey._kernels.closest_bvh import build_tree, nearest_in_tree


def _brute(p, tris):
    """Every triangle a candidate of every point (closest.nearest_triangles)."""
    start = np.arange(len(p) + 1, dtype=np.int64) * len(tris)
    cand = np.tile(np.arange(len(tris), dtype=np.int64), len(p))
    t, q = np.empty(len(p), dtype=np.int64), np.empty((len(p), 3))
    nearest_triangles(p, tris, start, cand, t, q)
    return t, q


def _tree(p, tris):
    t, q = np.empty(len(p), dtype=np.int64), np.empty((len(p), 3))
    nearest_in_tree(p, tris, *build_tree(tris), t, q)
    return t, q


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 300), st.integers(1, 200),
       st.sampled_from([1e-3, 1.0, 100.0]))
def test_tree_equals_brute_force(seed, m, n, scale):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-scale, scale, (m, 1, 3))
    tris = centres + rng.normal(0, scale / 10, (m, 3, 3))
    k = rng.integers(0, m, m // 5)
    tris[k, 2] = tris[k, 1]                          # degenerate: two equal vertices
    if m > 2:
        tris[-1] = tris[0]                           # an exact duplicate: a tie
    tris = np.ascontiguousarray(tris)
    p = np.vstack([rng.uniform(-1.5 * scale, 1.5 * scale, (n, 3)),
                   tris[rng.integers(0, m, 5), 0]])  # points on vertices: zero distance
    bt, bq = _brute(p, tris)
    tt, tq = _tree(p, tris)
    np.testing.assert_array_equal(tt, bt)
    np.testing.assert_array_equal(tq, bq)


def test_tree_shape_is_sound():
    rng = np.random.default_rng(3)
    tris = rng.normal(size=(1000, 3, 3))
    child, box, order = build_tree(tris)
    assert sorted(order) == list(range(1000))        # a permutation
    leaves = child[child[:, 0] < 0]
    assert leaves[:, 1].sum() == 1000 and leaves[:, 1].max() <= 4
    for i in np.flatnonzero(child[:, 0] >= 0):       # each child box holds its triangles
        for c in range(2):
            stack, tri = [child[i, c]], []
            while stack:
                j = stack.pop()
                if child[j, 0] < 0:
                    f = -1 - child[j, 0]
                    tri.extend(order[f:f + child[j, 1]])
                else:
                    stack.extend(child[j])
            t = tris[tri]
            assert (t.min(axis=(0, 1)) >= box[i, c, 0]).all()
            assert (t.max(axis=(0, 1)) <= box[i, c, 1]).all()


def test_tree_does_not_depend_on_the_thread_count():
    import numba

    tris = np.random.default_rng(5).normal(size=(5000, 3, 3))
    n = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = build_tree(tris)
    finally:
        numba.set_num_threads(n)
    for a, b in zip(one, build_tree(tris)):
        np.testing.assert_array_equal(a, b)
