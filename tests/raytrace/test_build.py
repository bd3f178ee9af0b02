"""BVH build kernels: the parallel top phase (stable partition between two row buffers)
against the serial build and against brute-force bounds."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import config
from raytrace._kernels import build

_ARGS = (config.SAH_BINS, True, config.SAH_C_TRAV, config.SAH_C_ISECT, config.MAX_LEAF_SIZE,
         config.MAX_LEAF_SIZE_FORCED)


def _soup(m, seed):
    """m random triangles (a clustered soup, so that SAH splits are uneven)."""
    rng = np.random.default_rng(seed)
    centre = rng.standard_normal((m, 3)) * rng.choice([0.2, 1.0, 5.0], size=(m, 1))
    v = (centre[:, None, :] + 0.05 * rng.standard_normal((m, 3, 3))).reshape(-1, 3)
    f = np.arange(3 * m).reshape(m, 3)
    prim = np.empty((m, 9), dtype=np.float32)
    good = np.empty(m, dtype=np.bool_)
    build.triangle_setup(v, f, config.AREA_REL, prim, good)
    return prim


def _build(prim, stop):
    p = prim.copy()
    idx = np.arange(len(p))
    node_box, node_meta = build.build_bvh(p, idx, *_ARGS, stop)
    return p, idx, node_box, node_meta


def _walk(node_box, node_meta):
    """(node, depth-first) list of the nodes reached from the root."""
    out, stack = [], [0]
    while stack:
        i = stack.pop()
        out.append(i)
        if node_meta[i, 3] == 0:
            stack += [node_meta[i, 1], node_meta[i, 0]]
    return out


def _leaf_sets(idx, node_box, node_meta):
    """Per leaf in walk order: (box bytes, sorted input indices)."""
    res = []
    for i in _walk(node_box, node_meta):
        if node_meta[i, 3] > 0:
            s, n = node_meta[i, 2], node_meta[i, 3]
            res.append((node_box[i].tobytes(), tuple(np.sort(idx[s:s + n]))))
    return res


@pytest.mark.parametrize("stop", [1, 4096])
def test_parallel_top_phase_builds_the_serial_tree(stop):
    """Big top-phase nodes are partitioned in parallel chunks (a stable partition into
    a second buffer); the tree must be the serial build's (stop >= m: everything in
    place), node for node, with only the row order inside a node free to differ."""
    m = 3 * build._PAR_BIN_MIN + 123
    prim = _soup(m, 3)
    p_ref, i_ref, box_ref, meta_ref = _build(prim, m)
    p, idx, box, meta = _build(prim, stop)
    walk_ref = _walk(box_ref, meta_ref)
    walk = _walk(box, meta)
    assert len(walk) == len(walk_ref)
    np.testing.assert_array_equal(box[walk], box_ref[walk_ref])
    np.testing.assert_array_equal(meta[walk, 2:], meta_ref[walk_ref, 2:])
    assert _leaf_sets(idx, box, meta) == _leaf_sets(i_ref, box_ref, meta_ref)
    # Rows travelled with their index (also those left in the second buffer).
    assert sorted(idx) == list(range(m))
    np.testing.assert_array_equal(p, prim[idx])


def test_node_boxes_are_tight_bounds_of_their_rows():
    """Every reached node's box is exactly the min/max over the boxes of its rows
    (brute force), for a build whose top phase runs the parallel partition."""
    m = 2 * build._PAR_BIN_MIN + 7
    prim = _soup(m, 11)
    p, idx, box, meta = _build(prim, 4096)
    # Rows of node i: the union of its leaves' ranges; compute bottom-up by recursion.
    rng_of = {}
    for i in reversed(_walk(box, meta)):
        if meta[i, 3] > 0:
            rng_of[i] = (meta[i, 2], meta[i, 2] + meta[i, 3])
        else:
            a, b = rng_of[meta[i, 0]], rng_of[meta[i, 1]]
            assert a[1] == b[0]  # children are adjacent row ranges
            rng_of[i] = (a[0], b[1])
    for i, (s, e) in rng_of.items():
        rows = p[s:e]
        want = np.concatenate([rows[:, 0:3].min(0), rows[:, 3:6].max(0)])
        np.testing.assert_array_equal(box[i], want)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 3000), lo_pad=st.integers(0, 5), k=st.integers(0, 14),
       axis=st.integers(0, 2), seed=st.integers(0, 2**31))
def test_partition_parallel_is_a_stable_partition(n, lo_pad, k, axis, seed):
    """Against NumPy's boolean-mask stable partition; rows outside [s, e) untouched;
    the centroid boxes of both sides are their rows' min/max."""
    rng = np.random.default_rng(seed)
    nb = 16
    m = n + lo_pad + 3
    prim = rng.random((m, 9)).astype(np.float32)
    idx = np.arange(m)
    s, e = lo_pad, lo_pad + n
    cbox = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
    scale = np.full(3, nb * (1.0 - 1e-6))
    b_cnt = np.zeros((3, nb), dtype=np.int64)
    b_box = np.empty((3, nb, 6))
    b_box[..., :3] = np.inf
    b_box[..., 3:] = -np.inf
    loc_cnt = np.zeros((build._PAR_BIN_CHUNKS, 3, nb), dtype=np.int64)
    build._bin_parallel(prim, s, e, cbox, scale, nb, b_cnt, b_box, loc_cnt)
    dst_p = np.full_like(prim, np.nan)
    dst_i = np.full_like(idx, -1)
    out = np.empty((4, 6))
    out[:, :3] = np.inf
    out[:, 3:] = -np.inf
    mid = build._partition_parallel(prim, idx, s, e, axis, 0.0, scale[axis], nb, k, loc_cnt,
                                    dst_p, dst_i, out)
    c = prim[s:e, 6 + axis].astype(np.float64)
    left = np.clip((c * scale[axis]).astype(np.int64), 0, nb - 1) <= k
    assert mid == s + left.sum()
    np.testing.assert_array_equal(dst_p[s:e], np.concatenate([prim[s:e][left],
                                                              prim[s:e][~left]]))
    np.testing.assert_array_equal(dst_i[s:e], np.concatenate([idx[s:e][left],
                                                              idx[s:e][~left]]))
    assert np.isnan(dst_p[:s]).all() and np.isnan(dst_p[e:]).all()
    for side, rows in ((2, prim[s:e][left]), (3, prim[s:e][~left])):
        if len(rows):
            np.testing.assert_array_equal(out[side, :3], rows[:, 6:].min(0))
            np.testing.assert_array_equal(out[side, 3:], rows[:, 6:].max(0))
        else:
            assert np.isinf(out[side]).all()
