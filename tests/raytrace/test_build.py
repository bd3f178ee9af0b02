"""BVH build kernels: the breadth-first parallel top phase against the serial build, the
whole build against a NumPy reference of Wald's binned SAH, node boxes against brute-force
bounds, the 8-lane box growth (``bounds8.grow8``) against its scalar twin, and the shared
task counter (``tasks.fetch_add``) of the parallel phases."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit, prange

from raytrace import config
from raytrace._kernels import bounds8, build, tasks
from tests.raytrace.cpu import needs_avx2

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
    build.triangle_setup(v, np.zeros(3), f, config.AREA_REL, prim, good)
    return prim


def _build(prim, stop, args=_ARGS):
    p = prim.copy()
    idx = np.arange(len(p))
    node_box, node_meta = build.build_bvh(p, idx, *args, stop)
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


@pytest.mark.parametrize("m, stop", [(3 * 4096 + 123, 1), (3 * 4096 + 123, 4096),
                                     (5 * 8192 + 77, 4096)])
def test_parallel_top_phase_builds_the_serial_tree(m, stop):
    """The parallel build (nodes above ``stop`` split as tasks on the shared queue) must
    build the serial build's tree (stop >= m: one worker, depth first), node for node.
    5 * 8192 + 77 rows: several levels of tasks."""
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
    (brute force), for a build that splits its top nodes as queue tasks."""
    m = 2 * 4096 + 7
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


# --------------------------------------------------------------------------- reference
def _half_area(lo, hi):
    d = hi.astype(np.float64) - lo.astype(np.float64)
    if (d < 0).any():
        return 0.0
    return d[0] * d[1] + d[1] * d[2] + d[2] * d[0]


def _reference_tree(prim, n_bins, c_trav, c_isect, max_leaf):
    """Wald 2007 binned SAH written plainly in NumPy, recursively, all three axes:
    returns the tree in depth-first order (left first) as a list of
    (count, box bytes, sorted rows) per node. Same constants and bin formula as the
    kernel; its own arithmetic (no fastmath, no SIMD, no work items)."""
    lo_all = prim[:, 0:3].astype(np.float64)
    hi_all = prim[:, 3:6].astype(np.float64)
    ce_all = prim[:, 6:9].astype(np.float64)
    out = []

    def node(rows):
        box = np.concatenate([prim[rows, 0:3].min(0), prim[rows, 3:6].max(0)])
        out.append((len(rows), box.astype(np.float32).tobytes(), tuple(np.sort(rows))))
        n = len(rows)
        if n == 1:
            return
        nb = min(n_bins, max(2, n))
        ce = ce_all[rows]
        clo, chi = ce.min(0), ce.max(0)
        best = (np.inf, -1, -1, None)
        for a in range(3):
            ext = chi[a] - clo[a]
            if not ext > 0.0:
                continue
            scale = nb * (1.0 - 1e-6) / ext
            k_of = np.clip(((ce[:, a] - clo[a]) * scale).astype(np.int64), 0, nb - 1)
            for k in range(nb - 1):
                left = k_of <= k
                n_l = int(left.sum())
                if n_l == 0 or n_l == n:
                    continue
                r_l, r_r = rows[left], rows[~left]
                cost = (_half_area(lo_all[r_l].min(0), hi_all[r_l].max(0)) * n_l
                        + _half_area(lo_all[r_r].min(0), hi_all[r_r].max(0)) * (n - n_l))
                if cost < best[0]:
                    best = (cost, a, k, left)
        assert best[1] >= 0, "the reference soup has no coincident centroids"
        area = _half_area(box[:3], box[3:])
        cost = c_trav + c_isect * best[0] / area if area > 0 else c_trav + c_isect * n
        if n <= max_leaf and c_isect * n <= cost:
            return
        node(rows[best[3]])
        node(rows[~best[3]])

    node(np.arange(len(prim)))
    return out


@pytest.mark.parametrize("m, seed, stop", [(700, 5, 4096), (4096 + 900, 8, 1)])
def test_build_equals_a_numpy_reference_sah_build(m, seed, stop):
    """The kernel's tree (8-lane float32 bins, breadth-first parallel top phase for the
    second case) is the plain binned SAH tree: same nodes in the same order, same boxes,
    same triangles under each node."""
    prim = _soup(m, seed)
    p, idx, box, meta = _build(prim, stop)
    got = []
    for i in _walk(box, meta):
        s = meta[i, 2]
        if meta[i, 3] > 0:
            rows = idx[s:s + meta[i, 3]]
        else:
            # An internal node's rows: from its first slot to the end of its last leaf.
            j = i
            while meta[j, 3] == 0:
                j = meta[j, 1]
            rows = idx[s:meta[j, 2] + meta[j, 3]]
        got.append((len(rows), box[i].tobytes(), tuple(np.sort(rows))))
    want = _reference_tree(prim, config.SAH_BINS, config.SAH_C_TRAV, config.SAH_C_ISECT,
                           config.MAX_LEAF_SIZE)
    assert len(got) == len(want)
    assert got == want


def test_coincident_centroids_are_split_by_index():
    """A node whose triangles share one centroid cannot be split by position: above
    MAX_LEAF_SIZE_FORCED it is halved by row, in the serial and the top phase alike."""
    m = 4096 + 1000
    tri = _soup(1, 0)
    prim = np.repeat(tri, m, axis=0)
    for stop in (m, 1):
        p, idx, box, meta = _build(prim, stop)
        leaves = [meta[i, 3] for i in _walk(box, meta) if meta[i, 3] > 0]
        assert sum(leaves) == m
        assert max(leaves) <= config.MAX_LEAF_SIZE_FORCED
        assert sorted(idx) == list(range(m))
        np.testing.assert_array_equal(box[0], np.concatenate([tri[0, :3], tri[0, 3:6]]))


# --------------------------------------------------------------------------- bounds8
@njit
def _grow_simd(dst, dst_off, src, src_off):
    bounds8.grow8(dst, dst_off, src, src_off)


_F32 = st.floats(width=32, allow_nan=True, allow_infinity=True)


@settings(max_examples=200, deadline=None)
@given(dst=st.lists(_F32, min_size=8, max_size=8), src=st.lists(_F32, min_size=11,
                                                                max_size=11),
       src_off=st.integers(0, 3))
def test_grow8_equals_its_scalar_twin(dst, src, src_off):
    """Bit for bit, NaN and infinite lanes included, at unaligned offsets."""
    d0 = np.array(dst, dtype=np.float32)
    s = np.array(src, dtype=np.float32)
    a, b = d0.copy(), d0.copy()
    _grow_simd(a, 0, s, src_off)
    bounds8.grow8_scalar(b, 0, s, src_off)
    np.testing.assert_array_equal(a.view(np.int32), b.view(np.int32))
    # The twin against NumPy on the lanes without NaN: min lanes 0-2, max lanes 3-7.
    p = s[src_off:src_off + 8]
    ok = ~(np.isnan(p) | np.isnan(d0))
    want = np.concatenate([np.minimum(d0[:3], p[:3]), np.maximum(d0[3:], p[3:])])
    np.testing.assert_array_equal(b[ok], want[ok])


@needs_avx2
def test_grow8_compiles_to_packed_avx():
    """A refactor that silently falls back to scalar code fails here: one packed
    maximum on 256 bits, a packed minimum (LLVM narrows it to the 128-bit half holding
    lanes 0-2) and a blend."""
    _grow_simd(np.zeros(8, np.float32), 0, np.zeros(9, np.float32), 1)
    asm = _grow_simd.inspect_asm(_grow_simd.signatures[0])
    assert re.search(r"\bvminps\b[^\n]*%[xy]mm", asm), "no packed vminps"
    assert re.search(r"\bvmaxps\b[^\n]*%ymm", asm), "no packed vmaxps on ymm"
    assert re.search(r"\bvblendps\b[^\n]*%ymm", asm), "no vblendps on ymm"


# --------------------------------------------------------------------------- tasks
@njit(parallel=True)
def _take_all(n_tasks, workers, taken, owner, counter):
    for t in prange(workers):
        while True:
            q = tasks.fetch_add(counter, 0, 1)
            if q >= n_tasks:
                break
            taken[q] += 1
            owner[q] = t
    return counter[0]


@pytest.mark.parametrize("workers", [1, 2, 5])
def test_fetch_add_hands_out_every_task_exactly_once(workers):
    """The shared counter of the parallel build: each of n tasks taken once, by some
    worker, and the counter ends at n + workers (each worker's last, failed take)."""
    n = 10_000
    taken = np.zeros(n, dtype=np.int64)
    owner = np.full(n, -1, dtype=np.int64)
    end = _take_all(n, workers, taken, owner, np.zeros(1, dtype=np.int64))
    np.testing.assert_array_equal(taken, np.ones(n, dtype=np.int64))
    assert owner.min() >= 0 and owner.max() < workers
    assert end == n + workers


@pytest.mark.parametrize("workers", [1, 2, 3, 5])
def test_task_queue_builds_the_same_tree_for_any_worker_count(workers):
    """The shared task queue (nodes split by whichever worker takes them, right child
    published, left child continued): for any worker count, more workers than threads
    included, every row ends where the one-worker build puts it, and the trees are the
    same node for node (numbering aside). Small ``stop`` values make many tasks."""
    m = 5 * 4096 + 77
    prim = _soup(m, 4)
    ref = prim.copy()
    ref_idx = np.arange(m)
    ref_box, ref_meta = build.build_bvh(ref, ref_idx, *_ARGS, m, workers=1)
    for stop in (1, 300, 4096):
        p = prim.copy()
        idx = np.arange(m)
        box, meta = build.build_bvh(p, idx, *_ARGS, stop, workers=workers)
        np.testing.assert_array_equal(idx, ref_idx)
        np.testing.assert_array_equal(p, ref)
        walk, walk_ref = _walk(box, meta), _walk(ref_box, ref_meta)
        assert len(walk) == len(walk_ref)
        np.testing.assert_array_equal(box[walk], ref_box[walk_ref])
        np.testing.assert_array_equal(meta[walk, 2:], ref_meta[walk_ref, 2:])
        # Every node is used once: the node ranges the workers reserved do not overlap.
        assert len(set(walk)) == len(walk) and max(walk) < 2 * m - 1


_GENERIC_SCRIPT = r"""
import json, sys
import numpy as np
from numba import njit
from raytrace._kernels import bounds8

@njit
def run(dst, src, n):
    for r in range(n):
        bounds8.grow8(dst, 8 * (r % 16), src, r)

if __name__ == "__main__":
    rng = np.random.default_rng(int(sys.argv[1]))
    src = rng.standard_normal(2008).astype(np.float32)
    src[rng.random(src.size) < 0.002] = np.inf
    src[rng.random(src.size) < 0.002] = -np.inf
    dst = np.empty(128, dtype=np.float32)
    dst.reshape(16, 8)[:, :3] = np.inf
    dst.reshape(16, 8)[:, 3:] = -np.inf
    run(dst, src, 400)
    print(json.dumps(dict(src=src.view(np.uint32).tolist(),
                          dst=dst.view(np.uint32).tolist())))
"""


def test_grow8_on_a_generic_cpu_equals_the_scalar_twin(tmp_path):
    """``NUMBA_CPU_NAME=generic`` (no AVX: LLVM splits the 8-lane vectors) runs grow8 in
    a subprocess with its own Numba cache; its bins must equal the scalar twin's, bit
    for bit, on the same input."""
    import json
    import os
    import subprocess
    import sys

    script = tmp_path / "generic_bounds8.py"
    script.write_text(_GENERIC_SCRIPT)
    env = dict(os.environ, NUMBA_CPU_NAME="generic", NUMBA_CPU_FEATURES="",
               NUMBA_CACHE_DIR=str(tmp_path / "numba_cache"))
    res = subprocess.run([sys.executable, str(script), "17"], capture_output=True,
                         text=True, env=env, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    src = np.array(out["src"], dtype=np.uint32).view(np.float32)
    want = np.empty(128, dtype=np.float32)
    want.reshape(16, 8)[:, :3] = np.inf
    want.reshape(16, 8)[:, 3:] = -np.inf
    for r in range(400):
        bounds8.grow8_scalar(want, 8 * (r % 16), src, r)
    assert 0 < np.isfinite(want).sum() < want.size  # finite and infinite lanes
    np.testing.assert_array_equal(np.array(out["dst"], dtype=np.uint32),
                                  want.view(np.uint32))
