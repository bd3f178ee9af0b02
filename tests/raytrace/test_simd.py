"""SIMD intrinsics (``raytrace/_kernels/simd.py``): each equals its scalar twin bit for bit,
the slab test is conservative against an exact rational slab test, the ordering sorts by
distance, the node test compiles to packed AVX instructions, and a generic (no-AVX) CPU
gets the same answers."""

from __future__ import annotations

import re
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numba import njit

from raytrace._kernels import simd
from tests.raytrace.cpu import generic_and_host, jit_call, needs_avx2

_F32_ANY = st.floats(width=32, allow_nan=True, allow_infinity=True)
_SPECIAL = st.sampled_from([0.0, -0.0, np.inf, -np.inf, np.nan, 1.0, -1.0, 1e-30, 3e38])
_F32 = st.one_of(_F32_ANY, _SPECIAL).map(np.float32)


@njit
def _slab_simd(planes, base, off, org, inv, t, dist):
    return simd.slab8(planes, base, off[0], off[1], off[2], org[0], org[1], org[2],
                      org[3], org[4], org[5], inv[0], inv[1], inv[2], t[0], t[1], dist)


@njit
def _slab_twin(planes, base, off, org, inv, t, dist):
    return simd.slab8_scalar(planes, base, off[0], off[1], off[2], org[0], org[1], org[2],
                             org[3], org[4], org[5], inv[0], inv[1], inv[2], t[0], t[1],
                             dist)


_order_simd = jit_call(simd.order8, 2)
_order_twin = jit_call(simd.order8_scalar, 2)
_load_simd = jit_call(simd.load8, 2)


@njit(error_model="numpy")
def _setup(o, d, t0, t1):
    """float64 ray -> slab8 arguments, as the traversal makes them."""
    off = np.empty(3, dtype=np.int64)
    org = np.empty(6, dtype=np.float32)
    inv = np.empty(3, dtype=np.float32)
    for a in range(3):
        off[a], org[a], org[3 + a], inv[a] = simd.axis_setup(o[a], d[a])
    t = np.empty(2, dtype=np.float32)
    t[0] = simd.round_down32(t0)
    t[1] = simd.round_up32(t1)
    return off, org, inv, t


def _bits(a):
    return np.asarray(a, dtype=np.float32).view(np.uint32)


@settings(max_examples=300, deadline=None)
@given(a=arrays(np.float32, 40, elements=_F32_ANY), i=st.integers(0, 32))
def test_load8_equals_scalar_twin(a, i):
    got = np.array(_load_simd(a, i), dtype=np.float32)
    want = np.array(simd.load8_scalar(a, i), dtype=np.float32)
    assert _bits(got).tolist() == _bits(want).tolist() == _bits(a[i:i + 8]).tolist()


@settings(max_examples=500, deadline=None)
@given(planes=arrays(np.float32, 2 * simd.PLANES, elements=st.one_of(_F32_ANY, _SPECIAL)),
       base=st.integers(0, simd.PLANES), off=st.tuples(*[st.sampled_from([0, 24])] * 3),
       org=st.lists(_F32, min_size=6, max_size=6), inv=st.lists(_F32, min_size=3, max_size=3),
       t=st.lists(_F32, min_size=2, max_size=2))
def test_slab8_equals_scalar_twin(planes, base, off, org, inv, t):
    """Any float32 input, NaN / inf planes and inf inverse directions included: same
    mask, same entry distances to the bit."""
    off = np.array(off, dtype=np.int64)
    org, inv, t = (np.array(x, dtype=np.float32) for x in (org, inv, t))
    d_simd = np.full(8, 7.0, dtype=np.float32)
    d_twin = np.full(8, -7.0, dtype=np.float32)
    m_simd = _slab_simd(planes, base, off, org, inv, t, d_simd)
    m_twin = _slab_twin(planes, base, off, org, inv, t, d_twin)
    assert m_simd == m_twin
    assert _bits(d_simd).tolist() == _bits(d_twin).tolist()
    # Missed lanes report +inf, hit lanes a non-NaN distance.
    for lane in range(8):
        if (m_simd >> lane) & 1:
            assert not np.isnan(d_simd[lane])
        else:
            assert d_simd[lane] == np.inf


@settings(max_examples=500, deadline=None)
@given(mask=st.integers(0, 255), dist=arrays(np.float32, 8, elements=_F32_ANY))
def test_order8_equals_scalar_twin(mask, dist):
    assert _order_simd(mask, dist) == _order_twin(mask, dist)


@settings(max_examples=300, deadline=None)
@given(mask=st.integers(0, 255),
       dist=arrays(np.float32, 8, elements=st.floats(0.0, np.inf, width=32)))
def test_order8_lists_the_hit_lanes_nearest_first(mask, dist):
    """Against a plain sort: the first ``count`` lanes are exactly the hit lanes, in
    non-decreasing distance (up to the documented 8-ulp key truncation), ties by lane."""
    count, order = _order_simd(mask, dist)
    lanes = [(order >> (4 * q)) & 15 for q in range(8)]
    hits = [k for k in range(8) if (mask >> k) & 1]
    assert count == len(hits)
    assert sorted(lanes) == list(range(8))
    assert sorted(lanes[:count]) == hits
    keys = [(int(_bits(dist[k])) >> 3, k) for k in lanes[:count]]
    assert keys == sorted(keys)
    assert lanes[count:] == sorted(lanes[count:])


def _exact_interval(lo, hi, o, d, t0, t1):
    """Exact (rational) [entry, exit] of the ray o + t d, t in [t0, t1], with the box
    [lo, hi]; None when empty."""
    enter, leave = Fraction(t0), (None if np.isinf(t1) else Fraction(t1))
    for a in range(3):
        la, ha, oa, da = (Fraction(float(x)) for x in (lo[a], hi[a], o[a], d[a]))
        if da == 0:
            if not la <= oa <= ha:
                return None
            continue
        ta, tb = (la - oa) / da, (ha - oa) / da
        if ta > tb:
            ta, tb = tb, ta
        enter = max(enter, ta)
        leave = tb if leave is None else min(leave, tb)
    return (enter, leave) if leave is None or enter <= leave else None


_COORD = st.floats(-1e3, 1e3, allow_nan=False)


@st.composite
def _grazing_case(draw):
    """Eight random boxes and a ray aimed at a corner, an edge or a face point of box 0
    (float32 planes), from up to ~1e4 away; some direction components exactly zero with
    the origin on a slab plane: the cases where rounding could cull a touched box."""
    lo = np.array([[draw(_COORD) for _ in range(3)] for _ in range(8)])
    ext = np.array([[draw(st.floats(0.0, 50.0)) for _ in range(3)] for _ in range(8)])
    lo32 = lo.astype(np.float32)
    hi32 = (lo + ext).astype(np.float32)
    hi32 = np.maximum(hi32, lo32)
    target = np.empty(3)
    for a in range(3):
        kind = draw(st.sampled_from(["lo", "hi", "in"]))
        target[a] = {"lo": lo32[0, a], "hi": hi32[0, a],
                     "in": lo32[0, a] + draw(st.floats(0, 1)) * (hi32[0, a] - lo32[0, a])}[kind]
    o = np.array([draw(st.floats(-1e4, 1e4)) for _ in range(3)])
    d = target - o
    for a in range(3):
        if draw(st.booleans()) and draw(st.booleans()):
            d[a] = draw(st.sampled_from([0.0, -0.0]))
            o[a] = target[a]
    if not np.any(d):
        d[0] = 1.0
    d = d / np.abs(d).max()  # first to ~1, so that the norm cannot underflow
    d = d / np.linalg.norm(d)
    t0 = draw(st.sampled_from([0.0, 0.0, 1e-3, 1.0]))
    t1 = draw(st.sampled_from([np.inf, np.inf, 1e2, 1e4]))
    t1 = max(t0, t1)
    return lo32, hi32, o, d, t0, t1


@settings(max_examples=400, deadline=None)
@given(case=_grazing_case())
def test_slab8_never_culls_a_box_the_exact_ray_touches(case):
    """Against exact rational arithmetic: every box the float64 ray touches within
    [t0, t1] is reported (float32 arithmetic with the rounded origins of ``axis_setup``
    and Ize's exit scaling), its entry distance is at most ENTRY_SLACK times the exact
    one; and boxes missed by a clear margin are not reported (the test does cull)."""
    lo32, hi32, o, d, t0, t1 = case
    planes = np.empty(simd.PLANES, dtype=np.float32)
    for a in range(3):
        planes[8 * a:8 * a + 8] = lo32[:, a]
        planes[24 + 8 * a:32 + 8 * a] = hi32[:, a]
    off, org, inv, t = _setup(o, d, t0, t1)
    dist = np.empty(8, dtype=np.float32)
    mask = _slab_simd(planes, 0, off, org, inv, t, dist)
    with np.errstate(divide="ignore", over="ignore"):
        loose_axes = int(np.sum((d != 0) & ~(np.abs(1.0 / d) <= np.finfo(np.float32).max)))
    for lane in range(8):
        exact = _exact_interval(lo32[lane], hi32[lane], o, d, t0, t1)
        if exact is not None:
            assert (mask >> lane) & 1, (lane, exact)
            assert Fraction(float(dist[lane])) <= exact[0] * Fraction(simd.ENTRY_SLACK)
        elif loose_axes == 0:
            # Clear misses (by 1e-4 of the coordinates' magnitude, at least 1e-4 m) must
            # be culled: widen the box and ask again. Not asked of rays with a direction
            # component whose inverse overflows float32: ``axis_setup`` deliberately
            # drops that axis's exit plane (conservative, documented there).
            pad = 1e-4 * (1.0 + np.abs(o).max() + float(np.abs(lo32[lane]).max())
                          + float(np.abs(hi32[lane]).max()))
            if _exact_interval(lo32[lane] - pad, hi32[lane] + pad, o, d, t0, t1) is None:
                assert not (mask >> lane) & 1, lane


@pytest.mark.parametrize("tiny", [4.86255338e-40, 1e-300, 5e-324, 2.9e-39, 1e-38])
def test_slab8_tiny_direction_component_whose_inverse_overflows_float32(tiny):
    """A ray o = (0, 1, tiny), d = (0, -1, -tiny) reaches the point box at the origin at
    t = 1 exactly (found by hypothesis): 1/d_z overflows float32 and must not turn the
    finite entry distance into +inf."""
    o = np.array([0.0, 1.0, tiny])
    d = np.array([0.0, -1.0, -tiny])
    lo32 = np.zeros((8, 3), np.float32)
    assert _exact_interval(lo32[0], lo32[0], o, d, 0.0, np.inf) is not None
    planes = np.zeros(simd.PLANES, dtype=np.float32)
    off, org, inv, t = _setup(o, d, 0.0, np.inf)
    dist = np.empty(8, dtype=np.float32)
    assert _slab_simd(planes, 0, off, org, inv, t, dist) == 255
    assert dist.tolist() == [1.0] * 8


@needs_avx2
def test_slab8_compiles_to_packed_avx():
    """A refactor that silently falls back to scalar code fails here: the node test
    must contain packed compares and maxima on 256-bit registers."""
    planes = np.zeros(simd.PLANES, dtype=np.float32)
    _slab_simd(planes, 0, np.zeros(3, np.int64), np.zeros(6, np.float32),
               np.ones(3, np.float32), np.array([0, np.inf], np.float32),
               np.empty(8, np.float32))
    asm = _slab_simd.inspect_asm(_slab_simd.signatures[0])
    assert re.search(r"\bvcmp\w*ps\b[^\n]*%ymm", asm), "no packed vcmpps on ymm"
    assert re.search(r"\bvmaxps\b[^\n]*%ymm", asm), "no packed vmaxps on ymm"
    assert re.search(r"\bvminps\b[^\n]*%ymm", asm), "no packed vminps on ymm"


_GENERIC_SCRIPT = r"""
import json, sys
import numpy as np
from numba import njit
from raytrace._kernels import simd

@njit
def run(planes, n, off, org, inv, t, dist, out_mask, out_order):
    for r in range(n):
        m = simd.slab8(planes, 48 * (r % 4), off[r, 0], off[r, 1], off[r, 2], org[r, 0],
                       org[r, 1], org[r, 2], org[r, 3], org[r, 4], org[r, 5], inv[r, 0],
                       inv[r, 1], inv[r, 2], t[r, 0], t[r, 1], dist[r])
        out_mask[r] = m
        c, o = simd.order8(m, dist[r])
        out_order[r, 0] = c
        out_order[r, 1] = o

def case(seed, n=500):
    rng = np.random.default_rng(seed)
    planes = rng.standard_normal(4 * 48).astype(np.float32)
    planes[rng.random(planes.size) < 0.05] = np.inf
    planes[rng.random(planes.size) < 0.05] = np.nan
    off = rng.choice([0, 24], size=(n, 3)).astype(np.int64)
    org = (0.5 * rng.standard_normal((n, 6))).astype(np.float32)
    inv = (1.0 / rng.standard_normal((n, 3))).astype(np.float32)
    inv[rng.random((n, 3)) < 0.1] = np.inf
    t = np.zeros((n, 2), dtype=np.float32)
    t[:, 1] = np.inf
    dist = np.empty((n, 8), dtype=np.float32)
    mask = np.empty(n, dtype=np.int64)
    order = np.empty((n, 2), dtype=np.int64)
    run(planes, n, off, org, inv, t, dist, mask, order)
    return dict(mask=mask.tolist(), order=order.tolist(),
                dist=dist.view(np.uint32).ravel().tolist())

if __name__ == "__main__":
    print(json.dumps(case(int(sys.argv[1]))))
"""


def test_generic_cpu_gives_the_same_results(tmp_path):
    """``NUMBA_CPU_NAME=generic`` (no AVX: LLVM splits the 8-lane vectors) runs the same
    kernels in a subprocess, with its own Numba cache directory, and must agree bit for
    bit with this process (the host CPU)."""
    generic, host = generic_and_host(tmp_path, "generic_simd", _GENERIC_SCRIPT)
    assert 0 < sum(m != 0 for m in host["mask"]) < len(host["mask"])  # mixed hits/misses
    assert generic == host


# ----------------------------------------------------------------- the 8-wide traversal
@pytest.mark.parametrize("tiny", [0.0, -0.0, 1e-40, -3e-39, 1e-300, 5e-324])
def test_traversal_with_tiny_direction_components_matches_brute_force(tiny):
    """End to end through ``Scene`` (8-wide records, float32 box test): rays from inside a
    closed sphere whose directions have components that are zero or whose inverse
    overflows float32, aimed at vertices and edge midpoints (the grazing cases), all hit
    (0 misses), and closest and any hit agree with brute-force float64 Möller–Trumbore
    (``tests/naive.py``): same triangle and t unless the winner is a tie within BARY."""
    from raytrace import Scene
    from raytrace.shapes import icosphere
    from tests.naive import naive_cast

    v, f = icosphere(2, radius=3.0)
    v = v + [0.25, -0.5, 0.125]  # off-centre: the sphere straddles the BVH's planes
    scene = Scene(v, f)
    origins, dirs = [], []
    for o in ([0.25, -0.5, 0.125], [1.0, 0.5, -0.25]):
        for a in range(3):
            for s in (1.0, -1.0):
                d = np.full(3, tiny)
                d[a] = s
                origins.append(o)
                dirs.append(d)
        # At vertices and edge midpoints, with one component made tiny.
        for p in list(v[:12]) + list(0.5 * (v[f[:8, 0]] + v[f[:8, 1]])):
            d = p - np.asarray(o)
            d[int(np.argmin(np.abs(d)))] = tiny
            origins.append(o)
            dirs.append(d)
    o, d = np.array(origins), np.array(dirs)
    hits = scene.cast(o, d, method="bvh")
    assert hits.hit.all()
    assert scene.occluded(o, d).all()
    t_ref, tri_ref, _, _, margin = naive_cast(v, f, o, d)
    same = hits.triangle == tri_ref
    # A different winner only where the brute force's winner grazes an edge (a tie).
    assert (same | (margin < 1e-6)).all()
    np.testing.assert_allclose(hits.t, t_ref, rtol=1e-9, atol=1e-12)
